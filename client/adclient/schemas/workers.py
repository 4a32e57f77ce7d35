"""Workers: leasing a trial, keeping and giving back its lease, the job a worker
evaluates, the artifacts it uploads, and the workers the server has seen."""

from __future__ import annotations

from datetime import datetime
from typing import Annotated, Any, Literal

from pydantic import (
    BaseModel,
    Field,
    SerializationInfo,
    SerializerFunctionWrapHandler,
    field_serializer,
)

from adclient.designs import Representation
from adclient.pruning import Checkpoint, PrunerConfig
from adclient.schemas.common import NAME_PATTERN, NO_NUL_PATTERN
from adclient.schemas.config import TaskConfig
from adclient.schemas.space import Space
from adclient.strict import StrictInput


class LeaseRequest(StrictInput):
    worker_id: str = Field(min_length=1, max_length=128, pattern=NO_NUL_PATTERN)
    tasks: list[Annotated[str, Field(pattern=NAME_PATTERN)]] | None = Field(
        default=None,
        max_length=256,
        description="lease only trials of studies whose task has one of these names "
        "(the tasks this worker can run); none: any task",
    )
    learners: list[Annotated[str, Field(pattern=NAME_PATTERN)]] | None = Field(
        default=None,
        max_length=256,
        description="lease only trials of studies whose task's learner has one of these "
        "names (the learners that load on this worker); none: any learner",
    )


class HeartbeatRequest(StrictInput):
    worker_id: str = Field(min_length=1, max_length=128, pattern=NO_NUL_PATTERN)


class ReleaseRequest(StrictInput):
    """The lease holder giving a trial back to the queue (``POST /trials/{id}/release``);
    an admin may name no worker, to take back a trial whatever holds it."""

    worker_id: str | None = Field(
        default=None, min_length=1, max_length=128, pattern=NO_NUL_PATTERN
    )


class HeartbeatResponse(BaseModel):
    trial_id: int
    lease_expires_at: datetime


class Job(BaseModel):
    """Everything a stateless worker needs to evaluate one trial.

    Its ``task``, ``space`` and ``pruner`` (the pruner's options too) travel without the
    fields at their defaults (a space keeps its ``type``): a worker that predates a field
    reads every job that leaves it at its default, and refuses (``errors.UnreadableJob``)
    only a job that uses it. A field's default is therefore part of the contract between
    servers and workers of different versions, and is not changed (docs/worker.md,
    "Workers older than the server"). Its JSON schema names the models all the same
    (a field with a default is not required)."""

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
    pruner: PrunerConfig = Field(
        default_factory=PrunerConfig,
        description="the study's pruner: with one, adworker evaluates and reports while "
        "it trains (every pruner.report_every steps) and stops when told",
    )
    resume: Checkpoint | None = Field(
        default=None,
        description="a promoted trial: download this checkpoint artifact and train on from "
        "its step to the budget instead of starting over",
    )
    transfer: TransferSource | None = Field(
        default=None,
        description="start the controller from this trial's checkpoint and train "
        "transfer.steps instead of the task's budget from scratch",
    )
    shared: SharedVersion | None = Field(
        default=None,
        description="a study with task.transfer shared, once its shared controller has a "
        "version: start from that version's weights (the artifact of the trial that made "
        "it) and train the warm budget; None in such a study: start from the study's "
        "initial weights at the full budget",
    )
    urdf: str | None = Field(
        default=None,
        description="a template study's robot: its template expanded at the params, once, "
        "by the server; None for a trial stored before the server kept URDFs, or from "
        "an older server (the worker expands the template itself then)",
    )

    @field_serializer("task", "space", "pruner", mode="wrap")
    def _without_defaults(
        self, config: BaseModel, _handler: SerializerFunctionWrapHandler, info: SerializationInfo
    ):
        # no return annotation: pydantic then keeps the models' JSON schema for these
        # fields (with one, the lease's OpenAPI schema says "object")
        dumped = config.model_dump(mode=info.mode, exclude_defaults=True)
        if isinstance(config, PrunerConfig):  # its options are a dict of its options model
            dumped.pop("options", None)
            options = config.parsed().model_dump(mode=info.mode, exclude_defaults=True)
            dumped.update({"options": options} if options else {})
        kind = getattr(config, "type", None)  # a space's discriminator
        return dumped if kind is None else {"type": kind, **dumped}


class TransferSource(BaseModel):
    """Where a job's controller starts (a study with ``task.transfer``): an evaluated
    design of the same study and tree, the nearest of its best."""

    trial_id: int = Field(description="the trial whose checkpoint the job starts from")
    artifact: str = Field(
        pattern=NAME_PATTERN, description="that trial's artifact holding the learner's state"
    )
    distance: float = Field(description="its spec distance to the job's design (0 to 1)")


SHARED_ARTIFACT = "shared-controller.npz"
"""The artifact in which a trial's worker uploads its update of the study's shared
controller (``task.transfer: shared``; its format: ``adworker.shared_weights``)."""


class SharedVersion(BaseModel):
    """A version of a study's shared controller (``task.transfer: shared``): the
    ``SHARED_ARTIFACT`` of the trial whose update made it (docs/worker.md, "A shared
    controller")."""

    version: int = Field(ge=1, description="1 for the first update, then one more each")
    trial_id: int = Field(description="the trial whose artifact holds its weights")
    artifact: str = Field(
        default=SHARED_ARTIFACT, pattern=NAME_PATTERN, description="that artifact's name"
    )
    updated_at: datetime | None = None


class SharedUpdate(StrictInput):
    """``POST /trials/{id}/shared-controller``: make the trial's uploaded
    ``SHARED_ARTIFACT`` the study's next shared version, if the study is still at
    ``base_version`` (null: it has none yet); else 409 naming the current version, so
    the worker merges onto it and asks again."""

    worker_id: str = Field(min_length=1, max_length=128, pattern=NO_NUL_PATTERN)
    base_version: int | None = Field(
        ge=1, description="the version the update was made from, or against (null: none)"
    )


class ArtifactInfo(BaseModel):
    name: str
    size: int
    content_type: str
    created_at: datetime


class WorkerInfo(BaseModel):
    worker_id: str
    last_seen_at: datetime
    current_trial_id: int | None
    state: Literal["working", "idle", "gone"] | None = Field(
        default=None,
        description="working: holds a trial; idle: holds none and was heard from in the "
        "server's last 90 s (an idle adworker asks for work at least every 30 s, a working "
        "one heartbeats at least every 20 s); gone: not heard from since (stopped, killed "
        "or cut off). Null from a server older than this field",
    )
    jobs_done: int
    jobs_failed: int
    tasks: list[str] | None = Field(
        default=None, description="the tasks it named at its latest lease; null: any task"
    )
    learners: list[str] | None = Field(
        default=None,
        description="the learners it named at its latest lease; null: any learner",
    )


class StudyServing(BaseModel):
    """Whether the workers seen lately serve a running managed study
    (``GET /studies/{id}/serving``): what ``adclient status`` and the dashboard say."""

    task: str
    learner: str
    external: bool
    recent_seconds: float = Field(description="a worker seen this recently is serving")
    serving: int = Field(description="recently seen workers that serve its task and learner")
    others: int = Field(description="recently seen workers that serve neither")
    idle_seconds: float | None = Field(
        description="how long the study has seen no activity with no trial running; "
        "null while a trial runs"
    )
    unserved: bool = Field(
        description="no recent worker serves it and it has been idle for the server's "
        "unserved_seconds: it waits for a worker that may never come"
    )
    text: str = Field(description="the same said for a person, with what to start")
