"""The task: built on adworker's simulator, imported only by the worker."""

from __future__ import annotations

from typing import ClassVar

from adplugin_reach import ReachUpOptions
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
