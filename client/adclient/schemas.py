"""The HTTP contract: every request and response body of the v1 API.

These pydantic models are the one source of truth shared by the server (which
validates and serialises with them) and by the SDK and workers (which parse with
them). Fields may be added; the paths, names and codes of v1 stay.
"""

from __future__ import annotations

import math
from datetime import datetime
from enum import StrEnum
from typing import Annotated, Any, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    GetJsonSchemaHandler,
    field_validator,
    model_validator,
)
from pydantic.json_schema import JsonSchemaValue
from pydantic_core import CoreSchema

from adclient.design import DesignSpace, Representation

NAME_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9_.\-]{0,127}$"
"""Names of studies, params, metrics and artifacts: safe in URLs, file names and XML."""
NO_NUL_PATTERN = r"^[^\x00]*$"
"""Free text: anything but NUL, which PostgreSQL cannot store in a text column."""

MAX_ASK = 64


class Direction(StrEnum):
    minimize = "minimize"
    maximize = "maximize"


class StudyState(StrEnum):
    running = "running"
    complete = "complete"
    stopped = "stopped"


class TrialState(StrEnum):
    queued = "queued"
    running = "running"
    complete = "complete"
    failed = "failed"


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


def _plain_text(value: Any, where: str) -> Any:
    """Refuse strings that cannot be stored and sent back: NUL (PostgreSQL cannot store
    it) and lone surrogates (not encodable as UTF-8), anywhere in a JSON value."""
    if isinstance(value, str):
        if "\x00" in value:
            raise ValueError(f"{where}: text must not contain NUL")
        try:
            value.encode("utf-8")
        except UnicodeEncodeError:
            raise ValueError(f"{where}: text must be valid Unicode (no lone surrogates)") from None
    elif isinstance(value, dict):
        for key, item in value.items():
            _plain_text(key, f"{where} key")
            _plain_text(item, f"{where}.{key}")
    elif isinstance(value, list):
        for index, item in enumerate(value):
            _plain_text(item, f"{where}[{index}]")
    return value


def _finite(value: float, what: str) -> float:
    if not math.isfinite(value):
        raise ValueError(f"{what} must be a finite number, got {value!r}")
    return value


class BoxParam(_Strict):
    name: str = Field(pattern=NAME_PATTERN)
    low: float
    high: float

    @model_validator(mode="after")
    def _check_bounds(self) -> BoxParam:
        _finite(self.low, f"param {self.name!r}: low")
        _finite(self.high, f"param {self.name!r}: high")
        if not self.low < self.high:
            raise ValueError(f"param {self.name!r}: low ({self.low}) must be < high ({self.high})")
        return self


class BoxSpace(_Strict):
    """A plain continuous box: each param searched between its bounds."""

    type: Literal["box"]
    params: list[BoxParam] = Field(min_length=1, max_length=256)

    @field_validator("params")
    @classmethod
    def _unique_names(cls, params: list[BoxParam]) -> list[BoxParam]:
        seen: set[str] = set()
        for param in params:
            if param.name in seen:
                raise ValueError(f"duplicate param name {param.name!r}")
            seen.add(param.name)
        return params


Space = Annotated[BoxSpace | DesignSpace, Field(discriminator="type")]


class ProposerConfig(_Strict):
    """Which proposer suggests new vectors, and how it starts."""

    name: str = Field(default="qei", pattern=NAME_PATTERN)
    n_initial: int = Field(default=2, ge=1, le=1000)
    seed: int = Field(default=0, ge=0, le=2**31 - 1)
    noisy: bool | None = Field(
        default=None,
        description="Model observation noise (qLogNEI). Default: true for managed studies.",
    )
    options: dict[str, Any] = Field(default_factory=dict)

    @field_validator("options")
    @classmethod
    def _options_text(cls, options: dict[str, Any]) -> dict[str, Any]:
        return _plain_text(options, "options")


class TaskConfig(_Strict):
    """What a worker does with a design: the task, the learner and their budgets."""

    name: str = Field(pattern=NAME_PATTERN)
    learner: str = Field(default="fast", pattern=NAME_PATTERN)
    train_steps: int | None = Field(default=None, ge=0, le=10_000_000)
    eval_episodes: int = Field(default=3, ge=1, le=100)
    episode_steps: int | None = Field(default=None, ge=1, le=100_000)
    seed: int = Field(default=0, ge=0, le=2**31 - 1)
    options: dict[str, Any] = Field(default_factory=dict)

    @field_validator("options")
    @classmethod
    def _options_text(cls, options: dict[str, Any]) -> dict[str, Any]:
        return _plain_text(options, "options")


class StudyCreate(_Strict):
    name: str = Field(pattern=NAME_PATTERN)
    direction: Direction = Direction.maximize
    space: Space
    proposer: ProposerConfig = Field(default_factory=ProposerConfig)
    task: TaskConfig | None = None
    max_trials: int | None = Field(default=None, ge=1, le=1_000_000)
    max_attempts: int = Field(default=3, ge=1, le=100)
    metadata: dict[str, Any] = Field(default_factory=dict)

    @field_validator("metadata")
    @classmethod
    def _metadata_text(cls, metadata: dict[str, Any]) -> dict[str, Any]:
        return _plain_text(metadata, "metadata")

    @model_validator(mode="after")
    def _managed_needs_budget(self) -> StudyCreate:
        if self.task is not None and self.max_trials is None:
            raise ValueError("max_trials is required for a study with a task (a managed study)")
        return self


class Study(BaseModel):
    id: int
    name: str
    direction: Direction
    state: StudyState
    managed: bool
    space: Space
    proposer: ProposerConfig
    task: TaskConfig | None
    max_trials: int | None
    max_attempts: int
    n_trials: int
    n_queued: int
    n_running: int
    n_complete: int
    n_failed: int
    best_value: float | None
    best_trial_id: int | None
    metadata: dict[str, Any]
    created_at: datetime
    updated_at: datetime


class AskRequest(_Strict):
    count: int = Field(default=1, ge=1, le=MAX_ASK)


class Trial(BaseModel):
    id: int
    study_id: int
    number: int
    state: TrialState
    params: dict[str, Any]
    vector: list[float]
    value: float | None
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


class AskResponse(BaseModel):
    trials: list[Trial]


class TellRequest(_Strict):
    """``{"value": v}`` completes a trial; ``{"state": "failed", "message": m}`` fails it.

    The published JSON schema says exactly that (one of two shapes), so generated
    clients and fuzzers see the same rule the validator enforces."""

    value: float | None = None
    state: Literal["complete", "failed"] = "complete"
    message: str | None = Field(default=None, max_length=10_000, pattern=NO_NUL_PATTERN)
    worker_id: str | None = Field(
        default=None, min_length=1, max_length=128, pattern=NO_NUL_PATTERN
    )
    metrics: dict[str, float] = Field(default_factory=dict, max_length=256)

    @model_validator(mode="after")
    def _consistent(self) -> TellRequest:
        if self.state == "complete":
            if self.value is None:
                raise ValueError("value is required to complete a trial")
            _finite(self.value, "value")
        elif self.value is not None:
            raise ValueError("a failed trial carries no value")
        for key, metric in self.metrics.items():
            _finite(metric, f"metric {key!r}")
        _plain_text(self.metrics, "metrics")
        _plain_text(self.message, "message")
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
                "state": {"const": "complete", "default": "complete"},
                **common,
            },
            "required": ["value"],
            "additionalProperties": False,
        }
        failed = {
            "type": "object",
            "title": "TellFailed",
            "properties": {"state": {"const": "failed"}, **common},
            "required": ["state"],
            "additionalProperties": False,
        }
        return {"title": "TellRequest", "description": cls.__doc__, "oneOf": [complete, failed]}


class LeaseRequest(_Strict):
    worker_id: str = Field(min_length=1, max_length=128, pattern=NO_NUL_PATTERN)


class HeartbeatRequest(_Strict):
    worker_id: str = Field(min_length=1, max_length=128, pattern=NO_NUL_PATTERN)


class HeartbeatResponse(BaseModel):
    trial_id: int
    lease_expires_at: datetime


class Job(BaseModel):
    """Everything a stateless worker needs to evaluate one trial."""

    trial_id: int
    study_id: int
    number: int
    attempt: int
    vector: list[float]
    params: dict[str, Any]
    task: TaskConfig
    space: Space
    representation: Representation | None
    lease_expires_at: datetime


class ArtifactInfo(BaseModel):
    name: str
    size: int
    content_type: str
    created_at: datetime


class WorkerInfo(BaseModel):
    worker_id: str
    last_seen_at: datetime
    current_trial_id: int | None
    jobs_done: int
    jobs_failed: int


class ErrorBody(BaseModel):
    """Every 4xx/5xx answer: a machine-readable code and a message naming what is wrong."""

    error: str
    detail: Any
    problems: list[str] | None = Field(default=None, description="each invalid field, named")
