"""walk-forward: a free robot travels as far along +x as it can in an episode.

The classic co-design benchmark, written as a plugin would write it: a Task on the
shared simulator and robot, declared (name, options model, factory) in
``adclient.builtin_tasks`` and registered through the ``activedesign.tasks`` entry
point like any third-party task.

The robot starts lying on the ground along +x (see ``adclient.spawn``), so forward is
the way its chain points. Metric: how far its centre of mass has moved along +x since
the episode began (m); score: that distance at the episode's end; reward: the progress
of each step, so an episode's return is its score. Sideways drift neither counts nor
costs. Walking repeats a motion, so the task gives the policy a gait clock
(``gait_period``): the fast learner then searches periodic gaits, and an RL policy
can time its steps. The episode ends early if the centre of mass rises above
``max_height``: a robot flung off the ground, or a diverged simulation, travels no
further.
"""

from __future__ import annotations

from typing import ClassVar

from adclient.builtin_tasks import WalkForwardOptions
from adworker.tasks.base import Task
from adworker.tasks.engine import EngineRobot, EngineSimulator
from adworker.tasks.snapshot import Snapshot


class WalkForward(Task[WalkForwardOptions]):
    name: ClassVar[str] = "walk-forward"
    fixed_base: ClassVar[bool] = False

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

    def _centre_of_mass(self, snapshot: Snapshot) -> tuple[float, float]:
        """(x, z) of the whole robot's centre of mass."""
        x = z = 0.0
        for k, weight in enumerate(self._weights):
            position = snapshot.position(k)
            x += weight * position[0]
            z += weight * position[2]
        return x, z

    def reset(self, snapshot: Snapshot) -> None:
        self._start, self._height = self._centre_of_mass(snapshot)
        self._distance = 0.0

    def metric(self, snapshot: Snapshot) -> float:
        x, self._height = self._centre_of_mass(snapshot)
        return x - self._start

    def reward(self, snapshot: Snapshot, metric: float) -> float:
        progress = metric - self._distance
        self._distance = metric
        return progress

    def terminated(self, snapshot: Snapshot) -> bool:
        return self._height > self.options.max_height

    def score(self, metric: list[float]) -> float:
        return metric[-1] if metric else 0.0
