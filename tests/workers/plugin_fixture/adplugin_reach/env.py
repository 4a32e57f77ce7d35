"""The task: built on adworker's simulator, imported only by the worker."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import ClassVar

import numpy as np

from adplugin_reach import ArmLengthOptions, ReachPointOptions, ReachUpOptions
from adworker.tasks.base import Task
from adworker.tasks.markers import Marker
from adworker.tasks.robot import Robot
from adworker.tasks.simulator import Simulator
from adworker.tasks.snapshot import Snapshot


class ReachUp(Task[ReachUpOptions]):
    name: ClassVar[str] = "reach-up"
    fixed_base: ClassVar[bool] = True
    reads_contacts: ClassVar[bool] = False

    def __init__(self, robot: Robot, sim: Simulator, options: ReachUpOptions) -> None:
        super().__init__(robot, sim, options)
        self.tip = robot.link_index(options.tip_link)

    def metric(self, snapshot: Snapshot) -> float:
        return snapshot.top[self.tip]


class ReachPoint(Task[ReachPointOptions]):
    """The tip of the tip link (its far end) reaches for ``target``; the task reports
    the tip's distance to it at the end of each episode and marks the target and the tip
    in the picture."""

    name: ClassVar[str] = "reach-point"
    fixed_base: ClassVar[bool] = True
    reads_contacts: ClassVar[bool] = False

    def __init__(self, robot: Robot, sim: Simulator, options: ReachPointOptions) -> None:
        super().__init__(robot, sim, options)
        self.tip = robot.link_index(options.tip_link)
        self.target = np.array(options.target)

    def _tip(self, snapshot: Snapshot) -> np.ndarray:
        half = self.robot.geometry[self.tip].length / 2
        return snapshot.centre(self.tip) + np.asarray(snapshot.axis(self.tip)) * half

    def metric(self, snapshot: Snapshot) -> float:
        return -float(np.linalg.norm(self._tip(snapshot) - self.target))

    def metrics(self, snapshot: Snapshot) -> Mapping[str, float]:
        return {"tip_distance": float(np.linalg.norm(self._tip(snapshot) - self.target))}

    def markers(self, snapshot: Snapshot) -> Sequence[Marker]:
        x, y, z = self._tip(snapshot).tolist()
        return [
            Marker(self.options.target, colour=(0.0, 0.8, 0.0), label="target"),
            Marker((x, y, z), colour=(0.0, 0.0, 1.0), label="tip"),
        ]


class ArmLength(Task[ArmLengthOptions]):
    """The arm's built length, whatever its controller does: a score of the design
    alone, known before it is simulated (tests of pruning and transfer choose it)."""

    name: ClassVar[str] = "arm-length"
    fixed_base: ClassVar[bool] = True
    reads_contacts: ClassVar[bool] = False

    def __init__(self, robot: Robot, sim: Simulator, options: ArmLengthOptions) -> None:
        super().__init__(robot, sim, options)
        self.length = sum(shape.length for shape in robot.model.shapes.values())

    def metric(self, snapshot: Snapshot) -> float:
        return self.length
