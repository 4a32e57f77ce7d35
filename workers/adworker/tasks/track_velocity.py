"""track-velocity: a free robot moves along +x at the speeds it is commanded.

Locomotion as a robotics user first asks for it: not as far as possible, but at a given
speed, and cheaply. The episode is split into equal parts, one per commanded speed of
``speeds`` (m/s), in turn; the policy observes the speed commanded now. Each control
step measures the robot's speed v: how far its centre of mass advanced along +x over
the last gait period (``gait_period``, or since the episode began where that is
shorter), divided by that time; and its tracking of the commanded speed c:
max(0, 1 - |v - c| / c), so 1 at the speed, 0 standing still, going backwards or at
twice it. A step where the body has fallen tracks nothing: walk-forward's rule
(:meth:`WalkForward.fallen`, ``fall_angle``), so diving forward is not moving at speed.

Metric per step: tracking less ``energy_weight`` times the motors' power as a fraction
of their peak (:meth:`EngineRobot.power_fraction`: sum of |torque x joint speed| at the
step's end over the sum of each joint's effort x velocity limit). Reward: the metric.
Score: the metric's mean over the episode's steps (an episode ended early, by
``max_height``, counts its missing steps as 0). Each evaluation episode reports
``task.speed`` (its mean measured speed while upright, m/s), ``task.power`` (its mean
power fraction) and walk-forward's ``task.fell``.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar

from adclient.builtin_tasks import TrackVelocityOptions
from adworker.tasks.base import DEFAULT_EPISODE_STEPS
from adworker.tasks.engine import EngineRobot, EngineSimulator
from adworker.tasks.snapshot import Snapshot
from adworker.tasks.walk_forward import WalkForward


class TrackVelocity(WalkForward):
    name: ClassVar[str] = "track-velocity"
    default_episode_steps: ClassVar[int] = 2 * DEFAULT_EPISODE_STEPS
    score_rule: ClassVar[str] = (
        "the per-step metric's mean over the episode's steps (missing steps count 0)"
    )
    options: TrackVelocityOptions

    def __init__(
        self, robot: EngineRobot, sim: EngineSimulator, options: TrackVelocityOptions
    ) -> None:
        super().__init__(robot, sim, options)
        self.steps = options.episode_steps or self.default_episode_steps
        self.speeds = list(options.speeds)
        self._window = max(1, round(options.gait_period / sim.control_period))
        self._period = sim.control_period
        self._xs: list[float] = []
        self._speeds: list[float] = []
        self._powers: list[float] = []

    def commanded(self) -> float:
        """The speed commanded at the coming step."""
        step = min(len(self._xs) - 1, self.steps - 1)
        return self.speeds[step * len(self.speeds) // self.steps]

    def observation_size(self) -> int:
        return 1

    def observation(self, snapshot: Snapshot) -> list[float]:
        return [self.commanded()]

    def reset(self, snapshot: Snapshot) -> None:
        super().reset(snapshot)
        self._xs = [self._start]
        self._speeds = []
        self._powers = []

    def metric(self, snapshot: Snapshot) -> float:
        command = self.commanded()
        x, self._height = self._centre_of_mass(snapshot)
        self._xs.append(x)
        back = min(self._window, len(self._xs) - 1)
        speed = (x - self._xs[-1 - back]) / (back * self._period)
        tracking = 0.0
        if not self.fallen(snapshot):
            tracking = max(0.0, 1.0 - abs(speed - command) / command)
            self._speeds.append(speed)
        power = self.robot.power_fraction(snapshot)
        self._powers.append(power)
        return tracking - self.options.energy_weight * power

    def reward(self, snapshot: Snapshot, metric: float) -> float:
        return metric

    def score(self, metric: list[float]) -> float:
        return sum(metric) / max(self.steps, len(metric)) if metric else 0.0

    def metrics(self, snapshot: Snapshot) -> Mapping[str, float]:
        mean_speed = sum(self._speeds) / len(self._speeds) if self._speeds else 0.0
        power = sum(self._powers) / len(self._powers) if self._powers else 0.0
        return {**super().metrics(snapshot), "speed": mean_speed, "power": power}
