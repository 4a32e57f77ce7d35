"""diagonal-gesture: an arm on a fixed base link points its distal link along (1, 1, 1).

The base link stands upright on the ground, fixed (its frame at the origin, the
chain at rest straight up along +z); two more links hang off it by two revolute
joints. Score (docs/method.md, "Tasks and their scores"): the cosine between the
distal link's direction (its frame's +z, base to tip) and the diagonal
(1, 1, 1)/sqrt(3), averaged over the second half of each evaluation episode. The
reward is that cosine per step.

At rest the cosine is 1/sqrt(3) = 0.577. Two parallel axes keep the distal link in
one plane through +z, so it reaches the diagonal only when that plane happens to
contain it; two non-parallel axes (for example one along x, one along y) reach it.

The task reports ``task.angle_deg``, the angle between the distal link and the
diagonal at the end of an evaluation episode (degrees, mean over the episodes), and
marks its target in the picture: where the distal link's tip would be, pointing along
the diagonal from where its parent end is (green, "target").
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import ClassVar

import numpy as np

from adclient.builtin_tasks import DiagonalGestureOptions
from adworker.tasks.base import Task
from adworker.tasks.engine import EngineRobot, EngineSimulator
from adworker.tasks.markers import Marker
from adworker.tasks.snapshot import Snapshot

INV_SQRT3 = 1.0 / math.sqrt(3.0)
DIAGONAL = np.full(3, INV_SQRT3)
TARGET_COLOUR = (0.1, 0.75, 0.2)


class DiagonalGesture(Task[DiagonalGestureOptions]):
    name: ClassVar[str] = "diagonal-gesture"
    fixed_base: ClassVar[bool] = True
    reads_contacts: ClassVar[bool] = False

    def __init__(
        self, robot: EngineRobot, sim: EngineSimulator, options: DiagonalGestureOptions
    ) -> None:
        super().__init__(robot, sim, options)
        self.distal = self.distal_index(robot, options.distal_link)

    @staticmethod
    def distal_index(robot: EngineRobot, distal: str | None) -> int:
        """The index of the link ``distal``, by default c if there is one, else the
        deepest link: the child of the last joint in the engine's (depth-first) order."""
        if distal is None:
            distal = "c" if "c" in robot.link_names else robot.joints[-1].child
        return robot.link_index(distal)

    def observation_size(self) -> int:
        return 3

    def observation(self, snapshot: Snapshot) -> list[float]:
        return list(snapshot.axis(self.distal))

    def metric(self, snapshot: Snapshot) -> float:
        x, y, z = snapshot.axis(self.distal)
        return (x + y + z) * INV_SQRT3

    def metrics(self, snapshot: Snapshot) -> Mapping[str, float]:
        cosine = max(-1.0, min(1.0, self.metric(snapshot)))
        return {"angle_deg": math.degrees(math.acos(cosine))}

    def markers(self, snapshot: Snapshot) -> Sequence[Marker]:
        length = self.robot.geometry[self.distal].length
        parent_end = snapshot.centre(self.distal) - np.asarray(snapshot.axis(self.distal)) * (
            length / 2
        )
        x, y, z = (float(value) for value in parent_end + DIAGONAL * length)
        return [Marker((x, y, z), TARGET_COLOUR, "target")]
