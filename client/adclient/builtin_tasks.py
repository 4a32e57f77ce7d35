"""The built-in tasks, declared as any plugin declares its own (entry points in
pyproject.toml). Their environments live in adworker; only the worker imports them."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, model_validator

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


CommandedSpeed = Annotated[float, Field(gt=0.0, le=5.0)]
Coordinate = Annotated[float, Field(ge=-10.0, le=10.0)]


class TrackVelocityOptions(WalkForwardOptions):
    speeds: list[CommandedSpeed] = Field(
        default=[0.2],
        min_length=1,
        max_length=4,
        description="The commanded forward speeds (m/s, each > 0 and at most 5): the "
        "episode is split into as many equal parts, each commanding its speed in turn",
    )
    energy_weight: float = Field(
        default=0.25,
        ge=0.0,
        le=10.0,
        description="What the motors' power costs: each step's tracking less this times "
        "their power as a fraction of their peak (sum of effort x velocity limit)",
    )


TRACK_VELOCITY = TaskSpec(
    name="track-velocity",
    options=TrackVelocityOptions,
    description="A free robot lying on the ground moves along +x at commanded speeds: "
    "the mean over the episode of each step's tracking (1 at the commanded speed, 0 at "
    "standing still, at twice it or while fallen) less the motors' normalised power.",
    factory="adworker.tasks.track_velocity:TrackVelocity.make_env",
    templates=True,
    simulators=SIMULATORS,
)


class ReachWorkspaceOptions(DiagonalGestureOptions):
    distal_link: LinkName | None = Field(
        default=None,
        description="The link whose far end (its tip) reaches the targets (default: c if "
        "there is one, else the child of the last joint); no joint moves the base",
    )
    targets: int = Field(
        default=4,
        ge=1,
        le=16,
        description="Targets per episode, drawn from the episode's seed, each held for an "
        "equal share of its steps",
    )
    centre: tuple[Coordinate, Coordinate, Coordinate] = Field(
        default=(0.25, 0.25, 0.75),
        description="The centre of the workspace, a ball the targets are drawn uniformly "
        "from (m, world; each coordinate -10 to 10)",
    )
    radius: float = Field(
        default=0.2, gt=0.0, le=5.0, description="The workspace ball's radius (m)"
    )
    tolerance: float = Field(
        default=0.1,
        gt=0.0,
        le=5.0,
        description="A target's success is exp(-d / tolerance), d the distal tip's "
        "distance from it (m): 1 on it, 0.37 at this distance, 0.05 at three times it",
    )

    @model_validator(mode="after")
    def _targets_fit(self) -> ReachWorkspaceOptions:
        if self.episode_steps is not None and self.targets > self.episode_steps:
            raise ValueError(
                f"targets ({self.targets}) must be at most episode_steps "
                f"({self.episode_steps}): each target holds for a share of the steps"
            )
        return self


REACH_WORKSPACE = TaskSpec(
    name="reach-workspace",
    options=ReachWorkspaceOptions,
    description="An arm on a base link fixed upright reaches targets drawn in a ball, one "
    "after another: the mean over the targets of exp(-d / tolerance), d its distal "
    "tip's distance from each at the end of that target's share of the episode.",
    factory="adworker.tasks.reach_workspace:ReachWorkspace.make_env",
    templates=True,
    fixed_base=True,
    simulators=SIMULATORS,
)


class CarryPayloadOptions(WalkForwardOptions):
    payload_link: LinkName | None = Field(
        default=None,
        description="The link the payload rests on at the start (default: the root)",
    )
    payload_mass: float = Field(default=0.2, gt=0.0, le=20.0, description="The payload's mass (kg)")
    payload_size: float = Field(
        default=0.05, ge=0.01, le=0.5, description="The side of the payload, a cube (m)"
    )
    direction: Literal["forward", "up"] = Field(
        default="forward",
        description="What counts as progress: the payload's travel along +x, or its rise",
    )

    def link_names(self) -> list[tuple[str, str]]:
        return [("payload_link", self.payload_link)] if self.payload_link is not None else []


CARRY_PAYLOAD = TaskSpec(
    name="carry-payload",
    options=CarryPayloadOptions,
    description="A free robot lying on the ground carries a box resting on one of its "
    "links: at the episode's end, how far the box has moved along +x (or risen), if it "
    "has never touched the ground and the body has not fallen (else no progress counts).",
    factory="adworker.tasks.carry_payload:CarryPayload.make_env",
    templates=True,
    simulators=SIMULATORS,
)
