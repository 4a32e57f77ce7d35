"""The pruning contract: a study's pruner and a trial's intermediate reports.

A worker (or an SDK loop) reports ``(step, value)`` while a trial runs
(``POST /api/v1/trials/{id}/report``); the server answers whether the study's pruner
would stop the trial there. A stopped trial is told ``{"state": "pruned"}``. Values are
on the objective's scale (a learner's evaluation score at that step), so a pruned
trial's last value can stand for it in the model (see docs/pruning.md).
"""

from __future__ import annotations

import math
from datetime import datetime
from typing import Any, Literal

from pydantic import BaseModel, Field, field_validator, model_validator

from adclient.ids import MAX_ID
from adclient.strict import StrictInput

MAX_STEP = 2**31 - 1
"""Steps are INTEGER columns (32-bit on PostgreSQL)."""

PRUNERS = ("none", "median", "asha")


class NoneOptions(StrictInput):
    """Never stop a trial (reports are still recorded)."""


class MedianOptions(StrictInput):
    """Optuna's MedianPruner: stop a trial whose best value so far is worse than the
    median of the complete trials' values at the same step."""

    n_startup_trials: int = Field(
        default=5, ge=0, le=1_000_000, description="complete trials before any pruning"
    )
    n_warmup_steps: int = Field(
        default=0, ge=0, le=MAX_STEP, description="steps of a trial before it can be pruned"
    )
    interval_steps: int = Field(
        default=1, ge=1, le=MAX_STEP, description="check every this many steps after warm-up"
    )
    n_min_trials: int = Field(
        default=1, ge=1, le=1_000_000, description="complete trials with a value at the step"
    )


class AshaOptions(StrictInput):
    """Asynchronous successive halving (Optuna's SuccessiveHalvingPruner): rungs at
    ``min_resource * reduction_factor**k`` learner steps; a trial reaching a rung goes on
    only if its value there is in the top ``1/reduction_factor`` of every trial's value at
    that rung so far."""

    min_resource: int = Field(default=1000, ge=1, le=MAX_STEP, description="first rung's step")
    reduction_factor: int = Field(default=3, ge=2, le=100)
    min_early_stopping_rate: int = Field(default=0, ge=0, le=30)
    max_resource: int | None = Field(
        default=None, ge=1, le=MAX_STEP, description="no rung at or beyond this step"
    )
    bootstrap_count: int = Field(
        default=0, ge=0, le=1000, description="trials a rung needs before it promotes any"
    )
    promotion: bool = Field(
        default=False,
        description="pause a trial stopped at a rung (adworker keeps its SB3 checkpoint as "
        "an artifact) instead of pruning it; promote it later, when it is in the rung's "
        "top 1/reduction_factor, and resume it from the checkpoint (docs/pruning.md)",
    )


PRUNER_OPTIONS: dict[str, type[StrictInput]] = {
    "none": NoneOptions,
    "median": MedianOptions,
    "asha": AshaOptions,
}


class PrunerConfig(StrictInput):
    """A study's pruner (study file ``pruner:``). ``pruned_as`` says what a pruned trial
    means to the proposer: its last reported value as an observation (the default), or
    nothing (left out, as Optuna's GP sampler does)."""

    name: Literal["none", "median", "asha"] = "none"
    options: dict[str, Any] = Field(default_factory=dict)
    pruned_as: Literal["last_value", "left_out"] = "last_value"
    report_every: int | None = Field(
        default=None,
        ge=1,
        le=MAX_STEP,
        description="learner steps between adworker's intermediate evaluations (each "
        "reported); default: a tenth of the training budget. Only with a pruner",
    )

    @model_validator(mode="after")
    def _known_options(self) -> PrunerConfig:
        model = PRUNER_OPTIONS[self.name]
        self.options = model.model_validate(self.options).model_dump()
        return self

    def parsed(self) -> MedianOptions | AshaOptions | NoneOptions:
        return PRUNER_OPTIONS[self.name].model_validate(self.options)  # type: ignore[return-value]


def _finite(value: float) -> float:
    if not math.isfinite(value):
        raise ValueError(f"value must be a finite number, not {value!r}")
    return value


class ReportRequest(StrictInput):
    """One intermediate value of a running trial: ``{"step": s, "value": v}``."""

    step: int = Field(ge=0, le=MAX_STEP, description="learner steps (or any increasing count)")
    value: float = Field(description="the objective's value at this step, finite")
    worker_id: str | None = Field(default=None, min_length=1, max_length=128, pattern=r"^[^\x00]*$")

    @field_validator("value")
    @classmethod
    def _finite_value(cls, value: float) -> float:
        return _finite(value)


class ReportResponse(BaseModel):
    should_stop: bool = Field(description="the study's pruner would stop the trial here")
    pause: bool = Field(
        default=False,
        description="stop by pausing (ASHA with promotion, a worker's report): upload a "
        "checkpoint artifact, then POST /trials/{id}/pause; a worker that cannot checkpoint "
        "tells the trial pruned instead",
    )


ARTIFACT_NAME = r"^[A-Za-z0-9][A-Za-z0-9_.\-]{0,127}$"
"""An artifact's name: ``adclient.schemas.common.NAME_PATTERN``, written out because
that package imports this module (tests/client/test_job_wire.py checks they agree)."""

CHECKPOINT_ARTIFACT = "checkpoint.zip"
"""The artifact adworker keeps a paused trial's learner state in."""


class Checkpoint(BaseModel):
    """Where a paused trial resumes from (``Trial.checkpoint``, ``Job.resume``)."""

    artifact: str = Field(
        pattern=ARTIFACT_NAME, description="the trial's artifact holding the learner's state"
    )
    step: int = Field(description="learner steps trained when it paused")
    rung: int = Field(description="the ASHA rung it waits at (its promotion is judged there)")
    metrics: dict[str, float] = Field(
        default_factory=dict,
        description="its metrics when it paused; a resumed job adds its own time to "
        "time_total_s and time_cpu_s",
    )
    lease: int | None = Field(
        default=None,
        description="the trial's lease (its count of leases) that uploaded the checkpoint "
        "and paused: a job resumes from the artifact only while it is still that upload",
    )
    budget: int | None = Field(
        default=None,
        description="the steps its job trains on to (a warm-started trial's warm budget); "
        "none: the task's budget",
    )

    @model_validator(mode="before")
    @classmethod
    def _budget_of_older_pauses(cls, data: Any) -> Any:
        """A pause stored, or sent by a worker, of the release before ``budget`` carried
        a warm start's budget only as its ``transfer_steps`` metric."""
        if isinstance(data, dict) and data.get("budget") is None:
            steps = (data.get("metrics") or {}).get("transfer_steps")
            if steps is not None:
                return {**data, "budget": int(steps)}
        return data


class PauseRequest(StrictInput):
    """The lease holder pauses its trial at ``step`` with the checkpoint it uploaded
    (``POST /api/v1/trials/{id}/pause``), as its study's ASHA pruner asked."""

    worker_id: str = Field(min_length=1, max_length=128, pattern=r"^[^\x00]*$")
    step: int = Field(ge=0, le=MAX_STEP, description="learner steps in the checkpoint")
    checkpoint: str = Field(
        default=CHECKPOINT_ARTIFACT,
        pattern=ARTIFACT_NAME,
        description="the name of the trial's artifact holding the checkpoint",
    )
    value: float | None = Field(default=None, description="default: the last reported value")
    metrics: dict[str, float] = Field(default_factory=dict, max_length=256)
    transfer_from: int | None = Field(
        default=None,
        ge=1,
        le=MAX_ID,
        strict=True,
        description="as a tell's: the trial its controller started from",
    )
    budget: int | None = Field(
        default=None,
        ge=1,
        le=MAX_STEP,
        strict=True,
        description="the steps the trial trains on to when promoted (a warm-started "
        "trial's warm budget); default: the task's budget",
    )

    @field_validator("value")
    @classmethod
    def _finite_value(cls, value: float | None) -> float | None:
        return None if value is None else _finite(value)

    @field_validator("metrics")
    @classmethod
    def _finite_metrics(cls, metrics: dict[str, float]) -> dict[str, float]:
        for metric in metrics.values():
            _finite(metric)
        return metrics


class TrialReport(BaseModel):
    """One point of a trial's reported curve (``GET /api/v1/trials/{id}/reports``)."""

    step: int
    value: float
    created_at: datetime


class TrialPruned(Exception):
    """Raise from an objective to end its trial as ``pruned`` (``study.optimize`` tells
    it so, with ``value`` or else the trial's last reported value), as Optuna's
    ``TrialPruned`` does."""

    def __init__(self, message: str = "", value: float | None = None) -> None:
        super().__init__(message)
        self.value = value
