"""Trials: asking for them, telling their outcomes, adding them to a study, their
attributes, and the pages and curves the dashboard draws from."""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Any, Literal

from pydantic import (
    BaseModel,
    Discriminator,
    Field,
    GetJsonSchemaHandler,
    Tag,
    model_validator,
)
from pydantic.json_schema import JsonSchemaValue
from pydantic_core import CoreSchema

from adclient.ids import MAX_ID
from adclient.objectives import MAX_OBJECTIVES
from adclient.pruning import Checkpoint
from adclient.schemas.common import (
    MAX_ASK,
    NO_NUL_PATTERN,
    JsonObject,
    StoredJsonObject,
    TrialState,
    finite,
    plain_text,
)
from adclient.schemas.studies import StudyUpdate
from adclient.strict import StrictInput


class TrialCurve(BaseModel):
    """One trial's reported curve, as the dashboard draws a study's learning curves."""

    trial_id: int
    number: int
    state: TrialState
    steps: list[int]
    values: list[float]


class StudyCurves(BaseModel):
    """The reported curves of a study's latest trials that reported, oldest first
    (``GET /api/v1/dashboard/studies/{id}/curves``)."""

    curves: list[TrialCurve]
    more: bool = Field(description="earlier trials reported too and are left out")


class TrialColumns(BaseModel):
    """A page of a study's trials as parallel columns, in order of number: the small
    payload charts draw from (``GET /studies/{id}/series``)."""

    number: list[int]
    state: list[TrialState]
    value: list[float | None]
    params: dict[str, list[str | bool | int | float | None]] = Field(
        description="each param that has a number (or, for a box's categorical param, a "
        "choice) in some trial of the page: its values (null where a trial has none)"
    )
    values: list[list[float] | None] | None = Field(
        default=None,
        description="a study of several objectives: each trial's objective values (null "
        "where it has none); null for a study of one objective",
    )
    feasible: list[bool | None] | None = Field(
        default=None,
        description="a study with constraints: whether each trial meets them (null where it "
        "has no outcome); null for a study without constraints",
    )
    next: int | None = Field(
        default=None,
        description="more trials follow: ask again with `after` set to this; null at the end",
    )


class AskRequest(StrictInput):
    count: int = Field(default=1, ge=1, le=MAX_ASK)


class Trial(BaseModel):
    id: int
    study_id: int
    number: int
    state: TrialState
    params: dict[str, Any]
    vector: list[float]
    value: float | None
    values: list[float] | None = Field(
        default=None, description="a study of several objectives: one value per objective"
    )
    feasible: bool | None = Field(
        default=None,
        description="whether a finished trial meets the study's constraints (null: the "
        "study has none, or the trial has no outcome)",
    )
    message: str | None = None
    metrics: dict[str, float] = Field(default_factory=dict)
    info: dict[str, Any] = Field(default_factory=dict, description="Proposer's notes")
    worker_id: str | None
    attempts: int = 0
    created_at: datetime
    started_at: datetime | None = None
    finished_at: datetime | None = None
    heartbeat_at: datetime | None = None
    lease_expires_at: datetime | None = None
    checkpoint: Checkpoint | None = Field(
        default=None, description="where a paused (or promoted) trial resumes from"
    )
    user_attrs: StoredJsonObject = Field(
        default_factory=dict, description="set with PATCH /trials/{id}"
    )


class TrialUpdate(StudyUpdate):
    """``PATCH /trials/{id}``: as :class:`StudyUpdate`; a worker setting attributes on
    the trial it runs (Optuna's objective calling ``trial.set_user_attr``) names itself
    in ``worker_id``, as it does to tell."""

    worker_id: str | None = Field(
        default=None, min_length=1, max_length=128, pattern=NO_NUL_PATTERN
    )


class AskResponse(BaseModel):
    trials: list[Trial]


class Spawn(BaseModel):
    """Where adworker's simulator puts a trial's robot before every episode
    (``adclient.spawn``): its root link's frame in the world (metres, z up, the ground
    at z = 0) and each driven joint's position (radians; metres for a prismatic joint)."""

    fixed_base: bool = Field(
        description="the study's task fixes the root where its URDF puts it; else the "
        "robot is free and set down on the ground"
    )
    position: tuple[float, float, float] = Field(description="the root frame's origin")
    orientation: tuple[float, float, float, float] = Field(
        description="the root frame's orientation, a unit quaternion (x, y, z, w)"
    )
    joints: dict[str, float] = Field(
        description="each driven joint by name: 0, or the limit nearest it; an episode "
        "starts here plus its random noise (task.options.init_noise)"
    )


class TellRequest(StrictInput):
    """``{"value": v}`` completes a trial; ``{"state": "failed", "message": m}`` fails it;
    ``{"state": "pruned"}`` (optionally with its last ``value``) ends it early, as its
    study's pruner asked.

    The published JSON schema says exactly that (one of two shapes), so generated
    clients and fuzzers see the same rule the validator enforces."""

    value: float | None = None
    values: list[float] | None = Field(default=None, min_length=1, max_length=MAX_OBJECTIVES)
    state: Literal["complete", "failed", "pruned"] = "complete"
    message: str | None = Field(default=None, max_length=10_000, pattern=NO_NUL_PATTERN)
    worker_id: str | None = Field(
        default=None, min_length=1, max_length=128, pattern=NO_NUL_PATTERN
    )
    metrics: dict[str, float] = Field(default_factory=dict, max_length=256)
    transfer_from: int | None = Field(
        default=None,
        ge=1,
        le=MAX_ID,
        strict=True,  # an id, never a boolean (true is not trial 1)
        description="the trial of the same study whose controller this one started from "
        "(task.transfer): a complete trial with a checkpoint a worker uploaded when it "
        "completed it; kept as the trial's info.transfer_from",
    )

    @model_validator(mode="after")
    def _consistent(self) -> TellRequest:
        if self.values is not None:
            _outcome_values(self.values, self.value, self.state)
            if len(self.values) == 1:  # one objective told as a list
                self.value, self.values = self.values[0], None
        elif self.state == "complete":
            if self.value is None:
                raise ValueError(
                    "value is required to complete a trial (values: several objectives)"
                )
            finite(self.value, "value")
        elif self.state == "pruned":
            if self.value is not None:
                finite(self.value, "value")
        elif self.value is not None:
            raise ValueError("a failed trial carries no value")
        for key, metric in self.metrics.items():
            finite(metric, f"metric {key!r}")
        plain_text(self.metrics, "metrics")
        plain_text(self.message, "message")
        return self

    @classmethod
    def __get_pydantic_json_schema__(
        cls, core_schema: CoreSchema, handler: GetJsonSchemaHandler
    ) -> JsonSchemaValue:
        schema = handler.resolve_ref_schema(handler(core_schema))
        common = {k: v for k, v in schema["properties"].items() if k not in ("value", "state")}
        complete = {
            "type": "object",
            "title": "TellComplete",
            "properties": {
                "value": {"type": "number"},
                "values": {
                    "type": "array",
                    "items": {"type": "number"},
                    "minItems": 1,
                    "maxItems": MAX_OBJECTIVES,
                    "description": "a study of several objectives: one number per objective",
                },
                "state": {"const": "complete", "default": "complete"},
                **common,
            },
            "oneOf": [{"required": ["value"]}, {"required": ["values"]}],
            "additionalProperties": False,
        }
        failed = {
            "type": "object",
            "title": "TellFailed",
            "properties": {"state": {"const": "failed"}, **common},
            "required": ["state"],
            "additionalProperties": False,
        }
        pruned = {
            "type": "object",
            "title": "TellPruned",
            "properties": {"state": {"const": "pruned"}, "value": {"type": "number"}, **common},
            "required": ["state"],
            "additionalProperties": False,
        }
        return {
            "title": "TellRequest",
            "description": cls.__doc__,
            "oneOf": [complete, failed, pruned],
        }


def _outcome_values(values: list[float], value: float | None, state: str) -> None:
    """``values`` of a tell or a handed-over trial: finite, instead of ``value``, and only
    for a complete trial."""
    if value is not None:
        raise ValueError("give value or values, not both")
    if state != "complete":
        raise ValueError(f"a {state} trial carries no values")
    for index, item in enumerate(values):
        finite(item, f"values[{index}]")


MAX_TRIALS_ADDED = 10_000
"""Trials one ``POST /studies/{id}/trials`` may add."""


class TrialAdd(StrictInput):
    """A trial handed to a study (``POST /studies/{id}/trials``).

    Without an outcome it is *enqueued*: a ``queued`` trial of these params, handed out
    before any proposal by the next ask (or leased by a worker, for a managed study),
    as Optuna's ``enqueue_trial``. With ``value`` (or ``state: failed``) it is an
    evaluation the user already has, stored finished and seen by the proposer (a warm
    start, as Optuna's ``add_trial``). ``params`` are checked against the study's space
    and stored as the study's own params (for a design space, the design they encode)."""

    params: JsonObject
    state: Literal["queued", "complete", "failed", "pruned"] | None = Field(
        default=None,
        description="default: complete with a value, queued without one",
    )
    value: float | None = None
    values: list[float] | None = Field(default=None, min_length=1, max_length=MAX_OBJECTIVES)
    message: str | None = Field(default=None, max_length=10_000, pattern=NO_NUL_PATTERN)
    metrics: dict[str, float] = Field(default_factory=dict, max_length=256)
    skip_if_exists: bool = Field(
        default=False,
        description="a trial of the same params already queued, running or finished "
        "(failed ones aside) is answered in place of a new one",
    )

    @model_validator(mode="after")
    def _consistent(self) -> TrialAdd:
        if self.state is None:
            told = self.value is not None or self.values is not None
            self.state = "complete" if told else "queued"
        if self.values is not None:
            _outcome_values(self.values, self.value, self.state)
            if len(self.values) == 1:
                self.value, self.values = self.values[0], None
        if self.state == "complete" and self.value is None and self.values is None:
            raise ValueError("value is required for a complete trial (values: several objectives)")
        if self.state in ("queued", "failed") and self.value is not None:
            raise ValueError(f"a {self.state} trial carries no value")
        if self.value is not None:
            finite(self.value, "value")
        if self.state == "queued" and (self.metrics or self.message is not None):
            raise ValueError("a queued trial carries no metrics or message")
        for key, metric in self.metrics.items():
            finite(metric, f"metric {key!r}")
        plain_text(self.metrics, "metrics")
        plain_text(self.message, "message")
        return self


TrialAdds = Annotated[list[TrialAdd], Field(min_length=1, max_length=MAX_TRIALS_ADDED)]
TrialAddBody = Annotated[
    Annotated[TrialAdd, Tag("trial")] | Annotated[TrialAdds, Tag("trials")],
    Discriminator(lambda body: "trials" if isinstance(body, list) else "trial"),
]
"""One trial (an object) or several (a list); an error names ``trial.<field>`` or
``trials.<index>.<field>``."""
