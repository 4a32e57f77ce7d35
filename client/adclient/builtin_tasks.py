"""The built-in tasks, declared as any plugin declares its own (entry points in
pyproject.toml). Their environments live in adworker; only the worker imports them."""

from __future__ import annotations

from typing import Annotated

from pydantic import Field

from adclient.plugins import SIMULATORS, SimulatorOptions, TaskSpec

LinkName = Annotated[str, Field(min_length=1, max_length=64)]


class StandUpOptions(SimulatorOptions):
    lifted_link: LinkName = Field(default="b", description="The link whose centre is lifted")
    feet_links: list[LinkName] = Field(
        default=["a", "c"],
        max_length=32,
        description="The links that must touch the ground while it counts",
    )

    def link_names(self) -> list[tuple[str, str]]:
        return [("lifted_link", self.lifted_link)] + [
            (f"feet_links[{index}]", name) for index, name in enumerate(self.feet_links)
        ]


class DiagonalGestureOptions(SimulatorOptions):
    distal_link: LinkName | None = Field(
        default=None,
        description="The link that points (default: c if there is one, else the child of "
        "the last joint)",
    )

    def link_names(self) -> list[tuple[str, str]]:
        return [("distal_link", self.distal_link)] if self.distal_link is not None else []


STAND_UP = TaskSpec(
    name="stand-up",
    options=StandUpOptions,
    description="A free three-link chain a-b-c lying on the ground lifts its middle link: "
    "the height of b's centre while a and c both touch the ground, else 0.",
    factory="adworker.tasks.stand_up:StandUp.make_env",
    templates=True,
    simulators=SIMULATORS,
)
DIAGONAL_GESTURE = TaskSpec(
    name="diagonal-gesture",
    options=DiagonalGestureOptions,
    description="An arm on a base link fixed upright points its distal link along "
    "(1, 1, 1): the cosine between the two directions.",
    factory="adworker.tasks.diagonal_gesture:DiagonalGesture.make_env",
    templates=True,
    fixed_base=True,
    simulators=SIMULATORS,
)
LIFT_HIGHEST = TaskSpec(
    name="lift-highest",
    options=SimulatorOptions,
    description="A free robot of any tree raises its highest point: the height of the "
    "top of its body.",
    factory="adworker.tasks.lift_highest:LiftHighest.make_env",
    templates=True,
    simulators=SIMULATORS,
)


class WalkForwardOptions(SimulatorOptions):
    gait_period: float = Field(
        default=0.8,
        gt=0.0,
        le=60.0,
        description="Seconds per cycle of the gait clock the policy sees (the fast learner "
        "searches gaits of this period)",
    )
    max_height: float = Field(
        default=3.0,
        gt=0.0,
        le=1000.0,
        description="The episode ends when the centre of mass rises above this (m): a robot "
        "flung off the ground, or a diverged simulation, travels no further",
    )
    fall_angle: float = Field(
        default=45.0,
        gt=0.0,
        le=90.0,
        description="Degrees past which the body has fallen: its root rolled onto its side "
        "(the axis level across it at the start tilted more than this) or over onto its back "
        "(the axis up at the start more than this below level). A fallen robot's progress "
        "does not count: its metric is then min(distance, 0). 90 never calls it fallen",
    )


WALK_FORWARD = TaskSpec(
    name="walk-forward",
    options=WalkForwardOptions,
    description="A free robot lying on the ground travels along +x: the distance its "
    "centre of mass has moved at the end of the episode (m), if it has not fallen (on its "
    "side or back: then no progress counts).",
    factory="adworker.tasks.walk_forward:WalkForward.make_env",
    templates=True,
    simulators=SIMULATORS,
)
