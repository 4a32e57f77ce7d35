"""walk-forward: a free robot travels as far along +x as it can in an episode.

The classic co-design benchmark, written as a plugin would write it: a Task on the
shared simulator and robot, declared (name, options model, factory) in
``adclient.builtin_tasks`` and registered through the ``activedesign.tasks`` entry
point like any third-party task.

The robot starts lying on the ground along +x (see ``adclient.spawn``), so forward is
the way its chain points. Metric: how far its centre of mass has moved along +x since
the episode began (m), while the body has not fallen; score: the metric at the
episode's end; reward: the metric's change each step, so an episode's return is its
score. Sideways drift neither counts nor costs.

Walking, not falling forward: a body that throws itself forward and lands on its side
covers its length without a step (issue 60: a quadruped scored 0.5 m that way). The
body has *fallen* while its root has rolled onto its side (the root's axis that was
level across +x at the start, world y, tilted more than ``fall_angle``) or over onto
its back (its axis that was up at the start more than ``fall_angle`` below level);
pitching up and down, as an inchworm's end link does, is neither. While fallen the
metric is min(distance, 0): no progress counts, and a fall cannot undo going backwards.
A robot that gets up again counts its distance again. Each evaluation episode reports
``task.fell``, 1 where it ended fallen (the trial's: the share of its episodes).

Walking repeats a motion, so the task gives the policy a gait clock (``gait_period``):
the fast learner then searches periodic gaits, and an RL policy can time its steps. The
episode ends early if the centre of mass rises above ``max_height``: a robot flung off
the ground, or a diverged simulation, travels no further.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import ClassVar

from adclient.builtin_tasks import WalkForwardOptions
from adworker.tasks.base import Task
from adworker.tasks.engine import EngineRobot, EngineSimulator
from adworker.tasks.snapshot import Snapshot


def _height_of(orientation: tuple[float, float, float, float], local: tuple[float, ...]) -> float:
    """The world z of the vector ``local`` (in a frame turned by the xyzw ``orientation``)."""
    x, y, z, w = orientation
    return (
        2.0 * (x * z - y * w) * local[0]
        + 2.0 * (y * z + x * w) * local[1]
        + (1.0 - 2.0 * (x * x + y * y)) * local[2]
    )


def _local(orientation: tuple[float, float, float, float], world: int) -> tuple[float, ...]:
    """World axis ``world`` (0 x, 1 y, 2 z) in the frame turned by ``orientation``: a row
    of its rotation matrix."""
    x, y, z, w = orientation
    rows = (
        (1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - z * w), 2.0 * (x * z + y * w)),
        (2.0 * (x * y + z * w), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - x * w)),
        (2.0 * (x * z - y * w), 2.0 * (y * z + x * w), 1.0 - 2.0 * (x * x + y * y)),
    )
    return rows[world]


class WalkForward(Task[WalkForwardOptions]):
    name: ClassVar[str] = "walk-forward"
    fixed_base: ClassVar[bool] = False
    score_rule: ClassVar[str] = "the per-step metric's last value (at the episode's end)"

    def __init__(
        self, robot: EngineRobot, sim: EngineSimulator, options: WalkForwardOptions
    ) -> None:
        super().__init__(robot, sim, options)
        self.gait_period = options.gait_period
        total = sum(g.mass for g in robot.geometry)
        self._weights = [g.mass / total for g in robot.geometry]
        self._start = 0.0
        self._distance = 0.0
        self._height = 0.0
        self._limit = math.sin(math.radians(options.fall_angle))
        self._side: tuple[float, ...] = (0.0, 1.0, 0.0)
        self._up: tuple[float, ...] = (0.0, 0.0, 1.0)

    def _centre_of_mass(self, snapshot: Snapshot) -> tuple[float, float]:
        """(x, z) of the whole robot's centre of mass."""
        x = z = 0.0
        for k, weight in enumerate(self._weights):
            position = snapshot.position(k)
            x += weight * position[0]
            z += weight * position[2]
        return x, z

    def fallen(self, snapshot: Snapshot) -> bool:
        """Whether the root lies on its side or its back (see the module docstring)."""
        orientation = snapshot.orientation(0)
        side = _height_of(orientation, self._side)
        up = _height_of(orientation, self._up)
        return abs(side) > self._limit or up < -self._limit

    def reset(self, snapshot: Snapshot) -> None:
        self._start, self._height = self._centre_of_mass(snapshot)
        self._distance = 0.0
        orientation = snapshot.orientation(0)
        self._side = _local(orientation, 1)  # world y and z at the start, in the root's frame
        self._up = _local(orientation, 2)

    def metric(self, snapshot: Snapshot) -> float:
        x, self._height = self._centre_of_mass(snapshot)
        distance = x - self._start
        return min(distance, 0.0) if self.fallen(snapshot) else distance

    def reward(self, snapshot: Snapshot, metric: float) -> float:
        progress = metric - self._distance
        self._distance = metric
        return progress

    def terminated(self, snapshot: Snapshot) -> bool:
        return self._height > self.options.max_height

    def score(self, metric: list[float]) -> float:
        return metric[-1] if metric else 0.0

    def metrics(self, snapshot: Snapshot) -> Mapping[str, float]:
        return {"fell": 1.0 if self.fallen(snapshot) else 0.0}
