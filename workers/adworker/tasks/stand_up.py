"""stand-up: a three-link chain a-b-c lying on the ground lifts its middle link.

Score (DESIGN.md section 3): the height of the centre of link b, averaged over the
second half of each evaluation episode, counted only while links a and c both touch
the ground (a step where either is off the ground counts as 0). The reward is the
same quantity per step, so every learner optimises what the score measures.

Parallel axes perpendicular to the chain and horizontal (theta = phi = pi/2 in the
initial pose, see ``RobotEnv._place_robot``) fold the chain into an arch standing on
a and c; axes along the links only roll the cylinders, and b stays at its radius.
"""

from __future__ import annotations

from typing import Any, ClassVar

from adworker.tasks.base import RobotEnv, Snapshot


class StandUpEnv(RobotEnv):
    task_name: ClassVar[str] = "stand-up"
    fixed_base: ClassVar[bool] = False

    def __init__(
        self,
        urdf_path: Any,
        options: dict[str, Any] | None = None,
        render_mode: str | None = None,
    ) -> None:
        super().__init__(urdf_path, options, render_mode)
        self.lifted = self.link_position(str(self.options.get("lifted_link", "b")))
        feet = self.options.get("feet_links", ["a", "c"])
        self.feet = [self.link_position(str(name)) for name in feet]

    def metric(self, snapshot: Snapshot) -> float:
        for k in self.feet:
            if not snapshot.touching[k]:
                return 0.0
        return snapshot.centre_z[self.lifted]
