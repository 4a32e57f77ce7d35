"""stand-up: a three-link chain a-b-c lying on the ground lifts its middle link.

Score (docs/method.md, "Tasks and their scores"): the height of the centre of link b,
averaged over the second half of each evaluation episode, counted only while links a and
c both touch the ground (a step where either is off the ground counts as 0). The reward is the
same quantity per step, so every learner optimises what the score measures.

Parallel axes perpendicular to the chain and horizontal (theta = phi = pi/2 in the
initial pose, see ``adclient.spawn``) fold the chain into an arch standing on
a and c; axes along the links only roll the cylinders, and b stays at its radius.
"""

from __future__ import annotations

from typing import ClassVar

from adclient.builtin_tasks import StandUpOptions
from adworker.tasks.base import Task
from adworker.tasks.engine import EngineRobot, EngineSimulator
from adworker.tasks.snapshot import Snapshot


class StandUp(Task[StandUpOptions]):
    name: ClassVar[str] = "stand-up"
    fixed_base: ClassVar[bool] = False

    def __init__(self, robot: EngineRobot, sim: EngineSimulator, options: StandUpOptions) -> None:
        super().__init__(robot, sim, options)
        self.lifted = robot.link_index(options.lifted_link)
        self.feet = [robot.link_index(name) for name in options.feet_links]

    def metric(self, snapshot: Snapshot) -> float:
        for k in self.feet:
            if not snapshot.touching[k]:
                return 0.0
        return snapshot.centre_z[self.lifted]
