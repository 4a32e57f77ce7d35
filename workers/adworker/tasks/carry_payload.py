"""carry-payload: a free robot carries a box forward (or lifts it) without dropping it.

At the start of every episode a cube (``payload_size`` m, ``payload_mass`` kg) rests
on top of ``payload_link`` (the root by default) of the robot lying on the ground (as
walk-forward's): a body of its own that touches the robot's links and the ground, held
only by friction and the robot's shape (:class:`~adworker.tasks.engine.PayloadSpec`,
built by either engine). The payload is *dropped* from the first step it touches the
ground: it stays dropped for the rest of the episode (a box kicked ahead along the
ground has not been carried).

Metric per step: the payload's progress since the start, along +x (``direction:
forward``) or up (``up``: how far its centre has risen), while it has not been dropped
and the body has not fallen (walk-forward's rule, :meth:`WalkForward.fallen`);
otherwise min(progress, 0): no progress counts, and losing the load cannot undo going
backwards. Score: the metric at the episode's end (walk-forward's). Reward: the
metric's change, so an episode's return is its score. Each evaluation episode reports
``task.dropped`` (1 where the payload was dropped) and ``task.fell``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import ClassVar

from adclient.builtin_tasks import CarryPayloadOptions
from adworker.tasks.engine import EngineRobot, EngineSimulator, PayloadSpec
from adworker.tasks.markers import Marker
from adworker.tasks.snapshot import Snapshot
from adworker.tasks.walk_forward import WalkForward

PAYLOAD_COLOUR = (0.9, 0.5, 0.1)


class CarryPayload(WalkForward):
    name: ClassVar[str] = "carry-payload"
    options: CarryPayloadOptions

    def __init__(
        self, robot: EngineRobot, sim: EngineSimulator, options: CarryPayloadOptions
    ) -> None:
        super().__init__(robot, sim, options)
        self._axis = 0 if options.direction == "forward" else 2
        self._payload_start = 0.0
        self.dropped = False

    @classmethod
    def payload(cls, options: CarryPayloadOptions) -> PayloadSpec | None:  # type: ignore[override]
        return PayloadSpec(options.payload_link, options.payload_mass, options.payload_size)

    def reset(self, snapshot: Snapshot) -> None:
        super().reset(snapshot)
        self._payload_start = self.robot.payload_state().position[self._axis]
        self.dropped = False

    def metric(self, snapshot: Snapshot) -> float:
        _, self._height = self._centre_of_mass(snapshot)
        state = self.robot.payload_state()
        self.dropped = self.dropped or state.on_ground
        progress = state.position[self._axis] - self._payload_start
        if self.dropped or self.fallen(snapshot):
            return min(progress, 0.0)
        return progress

    def metrics(self, snapshot: Snapshot) -> Mapping[str, float]:
        return {**super().metrics(snapshot), "dropped": 1.0 if self.dropped else 0.0}

    def markers(self, snapshot: Snapshot) -> Sequence[Marker]:
        x, y, z = self.robot.payload_state().position
        return [Marker((x, y, z), PAYLOAD_COLOUR, "dropped" if self.dropped else "payload")]
