"""The task: built on adworker's simulator, imported only by the worker."""

from __future__ import annotations

from typing import ClassVar

from adplugin_reach import ArmLengthOptions, ReachUpOptions
from adworker.tasks.base import Task
from adworker.tasks.robot import Robot
from adworker.tasks.simulator import Simulator
from adworker.tasks.snapshot import Snapshot


class ReachUp(Task[ReachUpOptions]):
    name: ClassVar[str] = "reach-up"
    fixed_base: ClassVar[bool] = True
    reads_contacts: ClassVar[bool] = False

    def __init__(self, robot: Robot, sim: Simulator, options: ReachUpOptions) -> None:
        super().__init__(robot, sim, options)
        self.tip = robot.link_position(options.tip_link)

    def metric(self, snapshot: Snapshot) -> float:
        return snapshot.top[self.tip]


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
