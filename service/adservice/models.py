"""SQLAlchemy tables. ORM rows never leave the service: routers return schemas."""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Any

import sqlalchemy as sa
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column
from sqlalchemy.types import TypeDecorator


def utcnow() -> datetime:
    return datetime.now(UTC)


class UTCDateTime(TypeDecorator[datetime]):
    """Stores naive UTC (portable across SQLite and PostgreSQL), returns aware UTC."""

    impl = sa.DateTime
    cache_ok = True

    def process_bind_param(self, value: datetime | None, dialect: Any) -> datetime | None:
        if value is None:
            return None
        if value.tzinfo is None:
            raise ValueError("naive datetime given to a UTC column")
        return value.astimezone(UTC).replace(tzinfo=None)

    def process_result_value(self, value: datetime | None, dialect: Any) -> datetime | None:
        return None if value is None else value.replace(tzinfo=UTC)


class Base(DeclarativeBase):
    pass


USER_ATTRS_DEFAULT = sa.text("'{}'")
"""Rows stored before user attributes (and trials inserted by Core statements that name
no such column) have none."""


class StudyRow(Base):
    __tablename__ = "studies"
    # Ids are never given again (SQLite would reuse the largest after a delete): a deleted
    # study's id must not come to mean another study in a URL, a cache or a worker.
    __table_args__ = {"sqlite_autoincrement": True}

    id: Mapped[int] = mapped_column(primary_key=True)
    name: Mapped[str] = mapped_column(sa.String(200))
    direction: Mapped[str] = mapped_column(sa.String(16))
    state: Mapped[str] = mapped_column(sa.String(16), default="running")
    space: Mapped[dict[str, Any]] = mapped_column(sa.JSON)
    proposer: Mapped[dict[str, Any]] = mapped_column(sa.JSON)
    pruner: Mapped[dict[str, Any]] = mapped_column(sa.JSON, default=lambda: {"name": "none"})
    # none_as_null: a study without a task must be SQL NULL, not the JSON text 'null',
    # or "managed studies" (task IS NOT NULL) would take in every study.
    task: Mapped[dict[str, Any] | None] = mapped_column(sa.JSON(none_as_null=True), nullable=True)
    representation: Mapped[dict[str, Any] | None] = mapped_column(
        sa.JSON(none_as_null=True), nullable=True
    )
    outcomes: Mapped[dict[str, Any] | None] = mapped_column(
        sa.JSON(none_as_null=True), nullable=True
    )
    """Several objectives or constraints (``adclient.objectives.outcomes_json``); None for
    one objective in ``direction``, which always holds the first objective's direction."""
    max_trials: Mapped[int | None] = mapped_column(nullable=True)
    max_attempts: Mapped[int] = mapped_column(default=3)
    n_trials: Mapped[int] = mapped_column(default=0)
    """Trial numbers given out (the next trial's number). How many trials are in each
    state is counted from the trials table, never kept here: a tell then writes this
    row only for a new best, so concurrent tells do not queue on it."""
    best_value: Mapped[float | None] = mapped_column(sa.Double, nullable=True)
    best_trial_id: Mapped[int | None] = mapped_column(nullable=True)
    metadata_: Mapped[dict[str, Any]] = mapped_column("metadata", sa.JSON, default=dict)
    user_attrs: Mapped[dict[str, Any]] = mapped_column(
        sa.JSON, default=dict, server_default=USER_ATTRS_DEFAULT
    )
    owner_token_id: Mapped[int | None] = mapped_column(nullable=True)
    """The token that created the study (None: created with auth off): a ``user`` token
    manages only the studies it owns."""
    created_by: Mapped[str | None] = mapped_column(sa.String(128), nullable=True)
    """The creating token's name, kept for display after the token is revoked."""
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)
    updated_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)
    proposal_error: Mapped[str | None] = mapped_column(sa.Text, nullable=True)
    """Why the study's last proposal failed (None: it succeeded, or none was made)."""
    proposal_failures: Mapped[int] = mapped_column(default=0, server_default=sa.text("0"))
    """Proposals failed in a row; reset by one that succeeds."""
    proposal_retry_at: Mapped[datetime | None] = mapped_column(UTCDateTime, nullable=True)
    """Before this time the lease scheduler skips the study (backoff after failures)."""
    proposal_fallbacks: Mapped[int] = mapped_column(default=0, server_default=sa.text("0"))
    """Candidates that were Sobol points because a budget or a failed model stopped the
    proposer (``proposers.base.DEGRADED``), over the study's life."""
    proposal_fallback_reason: Mapped[str | None] = mapped_column(sa.Text, nullable=True)
    """Why the latest model-phase ask fell back (None: it did not, or none was made)."""


class TrialRow(Base):
    __tablename__ = "trials"
    __table_args__ = (
        sa.UniqueConstraint("study_id", "number", name="uq_trials_study_number"),
        sa.Index("ix_trials_study_state", "study_id", "state"),
        sa.Index("ix_trials_state_lease", "state", "lease_expires_at"),
        {"sqlite_autoincrement": True},
    )

    id: Mapped[int] = mapped_column(primary_key=True)
    study_id: Mapped[int] = mapped_column(sa.ForeignKey("studies.id", ondelete="CASCADE"))
    number: Mapped[int]
    state: Mapped[str] = mapped_column(sa.String(16))
    vector: Mapped[list[float]] = mapped_column(sa.JSON)
    params: Mapped[dict[str, Any]] = mapped_column(sa.JSON)
    value: Mapped[float | None] = mapped_column(sa.Double, nullable=True)
    values: Mapped[list[float] | None] = mapped_column(sa.JSON(none_as_null=True), nullable=True)
    """A study of several objectives: one value per objective (``value`` is None then)."""
    feasible: Mapped[bool | None] = mapped_column(nullable=True)
    """Whether the trial meets its study's constraints (None: none, or no outcome)."""
    message: Mapped[str | None] = mapped_column(sa.Text, nullable=True)
    metrics: Mapped[dict[str, float]] = mapped_column(sa.JSON, default=dict)
    info: Mapped[dict[str, Any]] = mapped_column(sa.JSON, default=dict)
    worker_id: Mapped[str | None] = mapped_column(sa.String(128), nullable=True)
    attempts: Mapped[int] = mapped_column(default=0)
    leases: Mapped[int] = mapped_column(default=0, server_default=sa.text("0"))
    """How many times the trial was leased, never counted back (``attempts`` is, for a
    release or a pause): the number of its current lease, which an artifact uploaded
    under it records as its ``attempt``."""
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)
    started_at: Mapped[datetime | None] = mapped_column(UTCDateTime, nullable=True)
    finished_at: Mapped[datetime | None] = mapped_column(UTCDateTime, nullable=True)
    heartbeat_at: Mapped[datetime | None] = mapped_column(UTCDateTime, nullable=True)
    lease_expires_at: Mapped[datetime | None] = mapped_column(UTCDateTime, nullable=True)
    lease_token_id: Mapped[int | None] = mapped_column(nullable=True)
    """The token that holds the lease (None with auth off, where ``worker_id`` alone
    names the holder): only it may heartbeat, release, upload for or tell the trial."""
    checkpoint: Mapped[dict[str, Any] | None] = mapped_column(
        sa.JSON(none_as_null=True), nullable=True
    )
    """Where a paused trial resumes from (``adclient.pruning.Checkpoint``); kept after it
    is promoted, so a resumed job that loses its lease resumes from it again."""
    user_attrs: Mapped[dict[str, Any]] = mapped_column(sa.JSON, server_default=USER_ATTRS_DEFAULT)
    """No Python default: the hot path's prepared INSERT names its columns, and the
    database fills this one in."""


class TrialReportRow(Base):
    """One intermediate value of a trial (``POST /trials/{id}/report``); ``study_id`` is
    kept here too so a pruner reads a study's curves with one indexed query."""

    __tablename__ = "trial_reports"
    __table_args__ = (sa.Index("ix_trial_reports_study_step", "study_id", "step"),)

    trial_id: Mapped[int] = mapped_column(
        sa.ForeignKey("trials.id", ondelete="CASCADE"), primary_key=True
    )
    step: Mapped[int] = mapped_column(primary_key=True, autoincrement=False)
    study_id: Mapped[int] = mapped_column(sa.ForeignKey("studies.id", ondelete="CASCADE"))
    value: Mapped[float] = mapped_column(sa.Double)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)


class ArtifactRow(Base):
    __tablename__ = "artifacts"
    __table_args__ = (sa.UniqueConstraint("trial_id", "name", name="uq_artifacts_trial_name"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    trial_id: Mapped[int] = mapped_column(sa.ForeignKey("trials.id", ondelete="CASCADE"))
    name: Mapped[str] = mapped_column(sa.String(128))
    content_type: Mapped[str] = mapped_column(sa.String(128))
    size: Mapped[int]
    sha256: Mapped[str] = mapped_column(sa.String(64))
    path: Mapped[str] = mapped_column(sa.String(1024))
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)
    uploader: Mapped[str | None] = mapped_column(sa.String(16), nullable=True)
    """Who uploaded it: ``worker`` (under the trial's lease) or ``owner`` (an asked trial
    with no worker); None for files stored before this was recorded (never trusted)."""
    attempt: Mapped[int | None] = mapped_column(nullable=True)
    """The trial's lease (``TrialRow.leases``) it was uploaded under; None for an owner's
    upload (no lease)."""


class SharedControllerRow(Base):
    """A study's current shared controller (``task.transfer: shared``): its version and
    the trial whose uploaded ``SHARED_ARTIFACT`` holds it. A row of its own, so that
    advancing it (a compare-and-set on ``version``) never locks the study's row."""

    __tablename__ = "shared_controllers"

    study_id: Mapped[int] = mapped_column(
        sa.ForeignKey("studies.id", ondelete="CASCADE"), primary_key=True
    )
    version: Mapped[int]
    trial_id: Mapped[int] = mapped_column(sa.ForeignKey("trials.id", ondelete="CASCADE"))
    updated_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)


class NoteRow(Base):
    """A study's note (``trial_id`` None) or one of its trials' notes: free text its
    owner keeps. At most one per study or trial, kept so by writing under the study's
    row lock (``repository.notes``); each goes with its study or trial."""

    __tablename__ = "notes"
    __table_args__ = (sa.Index("ix_notes_study_trial", "study_id", "trial_id"),)

    id: Mapped[int] = mapped_column(primary_key=True)
    study_id: Mapped[int] = mapped_column(sa.ForeignKey("studies.id", ondelete="CASCADE"))
    trial_id: Mapped[int | None] = mapped_column(
        sa.ForeignKey("trials.id", ondelete="CASCADE"), nullable=True
    )
    text: Mapped[str] = mapped_column(sa.Text)
    updated_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)
    updated_by: Mapped[str | None] = mapped_column(sa.String(128), nullable=True)


class TrialURDFRow(Base):
    """A trial's URDF, expanded once from its study's template when its params were
    fixed; reads serve this text instead of expanding again. Exactly one of ``urdf``
    and ``error`` is set: a template that does not expand at the params is stored too,
    so no read expands it again."""

    __tablename__ = "trial_urdfs"

    trial_id: Mapped[int] = mapped_column(
        sa.ForeignKey("trials.id", ondelete="CASCADE"), primary_key=True
    )
    urdf: Mapped[str | None] = mapped_column(sa.Text, nullable=True)
    error: Mapped[str | None] = mapped_column(sa.Text, nullable=True)
    """Why the template does not expand at the trial's params (``urdf`` is None)."""
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)


class StudyStorageRow(Base):
    """The bytes a study stores: its trials' artifacts and stored URDFs. Kept by database
    triggers (migration 0015) in the transaction that adds or removes them, never written
    by the service: a new study gets its row, and each change passes on to its owner's
    :class:`OwnerStorageRow`."""

    __tablename__ = "study_storage"

    study_id: Mapped[int] = mapped_column(
        sa.ForeignKey("studies.id", ondelete="CASCADE"), primary_key=True, autoincrement=False
    )
    owner_key: Mapped[int]
    """The owning token's id, 0 for a study without an owner (``OwnerStorageRow``)."""
    artifact_bytes: Mapped[int] = mapped_column(sa.BigInteger)
    urdf_bytes: Mapped[int] = mapped_column(sa.BigInteger)
    """Each stored URDF's (or expansion error's) UTF-8 bytes."""


class OwnerStorageRow(Base):
    """The bytes all studies of one owner store (the sum of their ``StudyStorageRow``),
    which ``AD_OWNER_STORAGE_BYTES`` bounds; kept by triggers like its studies' rows.
    Studies without an owner (made with auth off) count as one owner, key 0."""

    __tablename__ = "owner_storage"

    owner_key: Mapped[int] = mapped_column(primary_key=True, autoincrement=False)
    bytes: Mapped[int] = mapped_column(sa.BigInteger)


class WorkerRow(Base):
    __tablename__ = "workers"

    worker_id: Mapped[str] = mapped_column(sa.String(128), primary_key=True)
    last_seen_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)
    current_trial_id: Mapped[int | None] = mapped_column(nullable=True)
    jobs_done: Mapped[int] = mapped_column(default=0)
    jobs_failed: Mapped[int] = mapped_column(default=0)
    tasks: Mapped[list[str] | None] = mapped_column(sa.JSON(none_as_null=True), nullable=True)
    """The tasks the worker named at its latest lease (None: any task)."""
    learners: Mapped[list[str] | None] = mapped_column(sa.JSON(none_as_null=True), nullable=True)
    """The learners the worker named at its latest lease (None: any learner)."""


class TokenRow(Base):
    """An API token: only its SHA-256 is stored (tokens are 256 random bits, so a fast
    hash is enough; the plain token is shown once, at creation)."""

    __tablename__ = "tokens"

    id: Mapped[int] = mapped_column(primary_key=True)
    name: Mapped[str] = mapped_column(sa.String(128))
    role: Mapped[str] = mapped_column(sa.String(16))
    token_sha256: Mapped[str] = mapped_column(sa.String(64), unique=True)
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)
    revoked_at: Mapped[datetime | None] = mapped_column(UTCDateTime, nullable=True)


class SessionRow(Base):
    """A dashboard sign-in: the browser holds a random id in an HttpOnly cookie, so the
    bearer token itself never reaches a page script; only the id's SHA-256 is stored."""

    __tablename__ = "sessions"

    id_sha256: Mapped[str] = mapped_column(sa.String(64), primary_key=True)
    token_id: Mapped[int] = mapped_column(sa.ForeignKey("tokens.id", ondelete="CASCADE"))
    csrf_token: Mapped[str] = mapped_column(sa.String(64))
    created_at: Mapped[datetime] = mapped_column(UTCDateTime, default=utcnow)
    expires_at: Mapped[datetime] = mapped_column(UTCDateTime)
