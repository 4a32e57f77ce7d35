"""The declarations only: light, so a server can read them without PyBullet."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field

from adclient.plugins import LearnerSpec, SimulatorOptions, TaskSpec


class ReachUpOptions(SimulatorOptions):
    tip_link: str = Field(default="c", min_length=1, description="The link whose top is scored")

    def link_names(self) -> list[tuple[str, str]]:
        return [("tip_link", self.tip_link)]


class ReachPointOptions(ReachUpOptions):
    target: tuple[
        Annotated[float, Field(ge=-5, le=5)],
        Annotated[float, Field(ge=-5, le=5)],
        Annotated[float, Field(ge=0, le=5)],
    ] = Field(default=(0.4, 0.3, 0.5), description="The point the tip reaches for (m)")


class ArmLengthOptions(SimulatorOptions):
    """arm-length has no options of its own."""


class HoldOptions(BaseModel):
    model_config = ConfigDict(extra="forbid")

    pose: float = Field(default=0.0, ge=-1.0, le=1.0, description="Every joint's target")


class StallOptions(BaseModel):
    model_config = ConfigDict(extra="forbid")

    way: Literal["sleep", "backtrack", "allocate", "none"] = Field(
        default="none",
        description="How it holds its worker: one sleep of an hour, a regular expression that "
        "backtracks for ever in C (holding the GIL), an allocation of 1 GiB, or not at all",
    )


REACH_UP = TaskSpec(
    name="reach-up",
    options=ReachUpOptions,
    description="An arm on a fixed base raises the top of its tip link as high as it can.",
    factory="adplugin_reach.env:ReachUp.make_env",
    fixed_base=True,
)
REACH_POINT = TaskSpec(
    name="reach-point",
    options=ReachPointOptions,
    description="An arm on a fixed base brings the tip of its tip link to a target point: "
    "minus the distance between them (m).",
    factory="adplugin_reach.env:ReachPoint.make_env",
    fixed_base=True,
)
REACH_ELSEWHERE = TaskSpec(
    name="reach-elsewhere",
    options=ReachUpOptions,
    description="reach-up on a simulator this machine does not have.",
    factory="adplugin_reach.elsewhere:make_env",
    fixed_base=True,
)
ARM_LENGTH = TaskSpec(
    name="arm-length",
    options=ArmLengthOptions,
    description="An arm on a fixed base scored by its links' total length, whatever it does.",
    factory="adplugin_reach.env:ArmLength.make_env",
    fixed_base=True,
)
HOLD = LearnerSpec(
    name="hold",
    description="No training: every joint holds one target.",
    factory="adplugin_reach.learner:Hold",
    options=HoldOptions,
)
STALL = LearnerSpec(
    name="stall",
    description="A hostile learner: it never returns from one call (or allocates 1 GiB), "
    "where no check of the worker's is reached; way none holds like hold.",
    factory="adplugin_reach.stall:Stall",
    options=StallOptions,
)
