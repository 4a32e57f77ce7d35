"""Repository: every read and write of studies, trials, workers and artifacts.

Functions take an open session (from ``Database.read``/``Database.write``, the one
place that commits) and keyword-only arguments; they raise domain errors and
return ORM rows, which ``adservice.convert`` turns into API schemas.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime, timedelta
from typing import Any

import numpy as np
import sqlalchemy as sa
from sqlalchemy.orm import Session

from adclient.schemas import StudyCreate, TellRequest, TrialState
from adservice.errors import ConflictError, LeaseLostError, NotFoundError
from adservice.models import ArtifactRow, StudyRow, TrialRow, WorkerRow, utcnow

TRIAL_ORDERS = {
    "number": TrialRow.number,
    "value": TrialRow.value,
    "state": TrialRow.state,
    "created_at": TrialRow.created_at,
    "finished_at": TrialRow.finished_at,
    "worker_id": TrialRow.worker_id,
    "attempts": TrialRow.attempts,
}


def _locking(session: Session) -> bool:
    """Row locks (``FOR UPDATE SKIP LOCKED``) where the database has them."""
    return session.get_bind().dialect.name == "postgresql"


# --- studies -------------------------------------------------------------------------


def create_study(
    session: Session, *, body: StudyCreate, representation: dict[str, Any] | None
) -> StudyRow:
    row = StudyRow(
        name=body.name,
        direction=body.direction.value,
        state="running",
        space=body.space.model_dump(mode="json"),
        proposer=body.proposer.model_dump(mode="json"),
        task=body.task.model_dump(mode="json") if body.task else None,
        representation=representation,
        max_trials=body.max_trials,
        max_attempts=body.max_attempts,
        metadata_=body.metadata,
    )
    session.add(row)
    session.flush()
    return row


def get_study(session: Session, *, study_id: int, for_update: bool = False) -> StudyRow:
    query = sa.select(StudyRow).where(StudyRow.id == study_id)
    if for_update and _locking(session):
        query = query.with_for_update()
    row = session.scalars(query).one_or_none()
    if row is None:
        raise NotFoundError(f"study {study_id} not found")
    return row


def list_studies(session: Session) -> list[StudyRow]:
    return list(session.scalars(sa.select(StudyRow).order_by(StudyRow.id)))


def state_counts(session: Session, *, study_ids: Sequence[int]) -> dict[int, dict[str, int]]:
    """Trials per state for each study: {study_id: {state: count}}."""
    counts: dict[int, dict[str, int]] = {sid: {} for sid in study_ids}
    if not study_ids:
        return counts
    rows = session.execute(
        sa.select(TrialRow.study_id, TrialRow.state, sa.func.count())
        .where(TrialRow.study_id.in_(study_ids))
        .group_by(TrialRow.study_id, TrialRow.state)
    )
    for study_id, state, count in rows:
        counts[study_id][state] = count
    return counts


def stop_study(session: Session, *, study_id: int) -> StudyRow:
    """Stop proposing and leasing; queued trials are dropped as failed."""
    study = get_study(session, study_id=study_id, for_update=True)
    if study.state != "running":
        return study
    now = utcnow()
    dropped = session.execute(
        sa.update(TrialRow)
        .where(TrialRow.study_id == study_id, TrialRow.state == TrialState.queued)
        .values(state=TrialState.failed, message="study stopped", finished_at=now)
    ).rowcount
    study.n_failed += dropped or 0
    study.state = "stopped"
    study.updated_at = now
    return study


# --- history for proposers ------------------------------------------------------------


@dataclass(frozen=True)
class History:
    """A study's trials as arrays, values as stored (not yet oriented)."""

    X: np.ndarray
    y: np.ndarray
    failed: np.ndarray
    pending: np.ndarray


def study_history(session: Session, *, study_id: int, dim: int) -> History:
    rows = session.execute(
        sa.select(TrialRow.state, TrialRow.vector, TrialRow.value)
        .where(TrialRow.study_id == study_id)
        .order_by(TrialRow.number)
    ).all()
    complete = [(v, y) for s, v, y in rows if s == TrialState.complete]
    empty = np.zeros((0, dim))

    def stack(vectors: list[list[float]]) -> np.ndarray:
        return np.asarray(vectors, dtype=np.float64).reshape(-1, dim) if vectors else empty

    return History(
        X=stack([v for v, _ in complete]),
        y=np.asarray([y for _, y in complete], dtype=np.float64),
        failed=stack([v for s, v, _ in rows if s == TrialState.failed]),
        pending=stack([v for s, v, _ in rows if s in (TrialState.queued, TrialState.running)]),
    )


# --- trials ---------------------------------------------------------------------------


def insert_trials(
    session: Session,
    *,
    study_id: int,
    vectors: Sequence[Sequence[float]],
    params: Sequence[dict[str, Any]],
    infos: Sequence[dict[str, Any]],
    worker_id: str | None = None,
    lease_seconds: float = 60.0,
) -> list[TrialRow]:
    """New trials in state ``running`` (leased to ``worker_id`` when given), numbered
    after the study's last; refused once ``max_trials`` would be exceeded."""
    study = get_study(session, study_id=study_id, for_update=True)
    count = len(vectors)
    check_room(study, count=count)
    first = study.n_trials
    study.n_trials += count
    now = utcnow()
    study.updated_at = now
    rows = []
    for offset, (vector, param, info) in enumerate(zip(vectors, params, infos, strict=True)):
        row = TrialRow(
            study_id=study_id,
            number=first + offset,
            state=TrialState.running,
            vector=[float(x) for x in vector],
            params=param,
            info=info,
            metrics={},
            worker_id=worker_id,
            attempts=1 if worker_id else 0,
            created_at=now,
            started_at=now,
            heartbeat_at=now if worker_id else None,
            lease_expires_at=now + timedelta(seconds=lease_seconds) if worker_id else None,
        )
        session.add(row)
        rows.append(row)
    session.flush()
    if worker_id:
        _touch_worker(session, worker_id=worker_id, now=now, current_trial_id=rows[0].id)
    return rows


def check_room(study: StudyRow, *, count: int) -> None:
    """Raise unless the study is running and has room for ``count`` more trials."""
    if study.state != "running":
        raise ConflictError(f"study {study.id} is {study.state}; it takes no new trials")
    if study.max_trials is not None and study.n_trials + count > study.max_trials:
        left = max(study.max_trials - study.n_trials, 0)
        raise ConflictError(
            f"study {study.id} has max_trials={study.max_trials} and {study.n_trials} "
            f"trials; {left} more can be asked"
        )


def get_trial(session: Session, *, trial_id: int, for_update: bool = False) -> TrialRow:
    query = sa.select(TrialRow).where(TrialRow.id == trial_id)
    if for_update and _locking(session):
        query = query.with_for_update()
    row = session.scalars(query).one_or_none()
    if row is None:
        raise NotFoundError(f"trial {trial_id} not found")
    return row


def list_trials(
    session: Session,
    *,
    study_id: int,
    state: TrialState | None = None,
    offset: int = 0,
    limit: int | None = None,
    order_by: str = "number",
    descending: bool = False,
) -> tuple[list[TrialRow], int]:
    """A page of a study's trials and the total that match."""
    get_study(session, study_id=study_id)
    where = [TrialRow.study_id == study_id]
    if state is not None:
        where.append(TrialRow.state == state.value)
    total = session.scalar(sa.select(sa.func.count()).select_from(TrialRow).where(*where)) or 0
    column = TRIAL_ORDERS[order_by]
    ordering = column.desc().nulls_last() if descending else column.asc().nulls_last()
    query = sa.select(TrialRow).where(*where).order_by(ordering, TrialRow.number)
    query = query.offset(offset)
    if limit is not None:
        query = query.limit(limit)
    return list(session.scalars(query)), total


def best_trial(session: Session, *, study_id: int) -> TrialRow:
    study = get_study(session, study_id=study_id)
    if study.best_trial_id is None:
        raise NotFoundError(f"study {study_id} has no complete trial yet")
    return get_trial(session, trial_id=study.best_trial_id)


def _is_better(direction: str, value: float, best: float | None) -> bool:
    if best is None:
        return True
    return value > best if direction == "maximize" else value < best


def _same_tell(trial: TrialRow, body: TellRequest) -> bool:
    if trial.state != body.state:
        return False
    if body.state == "failed":
        return True
    assert trial.value is not None and body.value is not None
    return trial.value == body.value or math.isclose(trial.value, body.value, rel_tol=1e-12)


def tell_trial(session: Session, *, trial_id: int, body: TellRequest) -> TrialRow:
    """Finish a trial. Repeating an identical tell is harmless; a contradicting one is
    a conflict; a worker that no longer holds the lease is told so."""
    trial = get_trial(session, trial_id=trial_id, for_update=True)
    if trial.state in (TrialState.complete, TrialState.failed):
        if _same_tell(trial, body):
            return trial
        told = f"value {trial.value}" if trial.state == TrialState.complete else "failed"
        raise ConflictError(f"trial {trial_id} is already {trial.state} ({told})")
    if body.worker_id is not None and (
        trial.state != TrialState.running or trial.worker_id != body.worker_id
    ):
        raise LeaseLostError(
            f"worker {body.worker_id!r} does not hold the lease of trial {trial_id}"
        )
    study = get_study(session, study_id=trial.study_id, for_update=True)
    now = utcnow()
    trial.state = body.state
    trial.value = body.value
    trial.message = body.message
    trial.metrics = dict(body.metrics)
    trial.finished_at = now
    trial.lease_expires_at = None
    if trial.started_at is None:
        trial.started_at = now
    if body.state == "complete":
        assert body.value is not None
        study.n_complete += 1
        if _is_better(study.direction, body.value, study.best_value):
            study.best_value = body.value
            study.best_trial_id = trial.id
    else:
        study.n_failed += 1
    _finish_study_if_done(study)
    study.updated_at = now
    if trial.worker_id is not None:
        worker = session.get(WorkerRow, trial.worker_id)
        if worker is not None:
            if body.state == "complete":
                worker.jobs_done += 1
            else:
                worker.jobs_failed += 1
            worker.last_seen_at = now
            if worker.current_trial_id == trial.id:
                worker.current_trial_id = None
    return trial


def _finish_study_if_done(study: StudyRow) -> None:
    if (
        study.state == "running"
        and study.max_trials is not None
        and study.n_complete + study.n_failed >= study.max_trials
    ):
        study.state = "complete"


# --- leases ---------------------------------------------------------------------------


def expire_leases(session: Session, *, now: datetime | None = None) -> int:
    """Send trials whose lease ran out back to the queue, or fail them after
    ``max_attempts``. Returns how many leases expired."""
    now = now or utcnow()
    query = (
        sa.select(TrialRow, StudyRow)
        .join(StudyRow, StudyRow.id == TrialRow.study_id)
        .where(TrialRow.state == TrialState.running, TrialRow.lease_expires_at < now)
    )
    if _locking(session):
        query = query.with_for_update(of=TrialRow, skip_locked=True)
    expired = session.execute(query).all()
    for trial, study in expired:
        worker = session.get(WorkerRow, trial.worker_id) if trial.worker_id else None
        if worker is not None and worker.current_trial_id == trial.id:
            worker.current_trial_id = None
        trial.lease_expires_at = None
        if trial.attempts >= study.max_attempts:
            trial.state = TrialState.failed
            trial.message = f"lease expired on each of {trial.attempts} attempts"
            trial.finished_at = now
            study.n_failed += 1
            if worker is not None:
                worker.jobs_failed += 1
            _finish_study_if_done(study)
        else:
            trial.state = TrialState.queued
            trial.worker_id = None
        study.updated_at = now
    return len(expired)


def lease_queued_trial(
    session: Session, *, worker_id: str, lease_seconds: float
) -> TrialRow | None:
    """Lease the oldest queued trial of a running managed study, if any."""
    now = utcnow()
    expire_leases(session, now=now)
    query = (
        sa.select(TrialRow)
        .join(StudyRow, StudyRow.id == TrialRow.study_id)
        .where(
            TrialRow.state == TrialState.queued,
            StudyRow.state == "running",
            StudyRow.task.is_not(None),
        )
        .order_by(TrialRow.id)
        .limit(1)
    )
    if _locking(session):
        query = query.with_for_update(of=TrialRow, skip_locked=True)
    trial = session.scalars(query).one_or_none()
    if trial is None:
        _touch_worker(session, worker_id=worker_id, now=now, current_trial_id=None)
        return None
    trial.state = TrialState.running
    trial.worker_id = worker_id
    trial.attempts += 1
    trial.started_at = now
    trial.heartbeat_at = now
    trial.lease_expires_at = now + timedelta(seconds=lease_seconds)
    _touch_worker(session, worker_id=worker_id, now=now, current_trial_id=trial.id)
    return trial


def studies_wanting_trials(session: Session) -> list[int]:
    """Running managed studies with room for another trial, oldest first."""
    query = (
        sa.select(StudyRow.id)
        .where(
            StudyRow.state == "running",
            StudyRow.task.is_not(None),
            StudyRow.n_trials < StudyRow.max_trials,
        )
        .order_by(StudyRow.id)
    )
    return list(session.scalars(query))


def heartbeat(session: Session, *, trial_id: int, worker_id: str, lease_seconds: float) -> TrialRow:
    trial = get_trial(session, trial_id=trial_id, for_update=True)
    if trial.state != TrialState.running or trial.worker_id != worker_id:
        raise LeaseLostError(f"worker {worker_id!r} does not hold the lease of trial {trial_id}")
    now = utcnow()
    trial.heartbeat_at = now
    trial.lease_expires_at = now + timedelta(seconds=lease_seconds)
    _touch_worker(session, worker_id=worker_id, now=now, current_trial_id=trial.id)
    return trial


def _touch_worker(
    session: Session, *, worker_id: str, now: datetime, current_trial_id: int | None
) -> None:
    worker = session.get(WorkerRow, worker_id)
    if worker is None:
        worker = WorkerRow(worker_id=worker_id, jobs_done=0, jobs_failed=0)
        session.add(worker)
    worker.last_seen_at = now
    worker.current_trial_id = current_trial_id


def list_workers(session: Session, *, study_id: int | None = None) -> list[WorkerRow]:
    """All workers, or those that ever held a trial of ``study_id``."""
    query = sa.select(WorkerRow).order_by(WorkerRow.last_seen_at.desc())
    if study_id is not None:
        get_study(session, study_id=study_id)
        held = sa.select(TrialRow.worker_id).where(TrialRow.study_id == study_id).distinct()
        query = query.where(WorkerRow.worker_id.in_(held))
    return list(session.scalars(query))


# --- artifacts ------------------------------------------------------------------------


def record_artifact(
    session: Session,
    *,
    trial_id: int,
    name: str,
    content_type: str,
    size: int,
    sha256: str,
    path: str,
) -> ArtifactRow:
    """Record an artifact whose file is already complete on disk (last step of a PUT)."""
    get_trial(session, trial_id=trial_id)
    row = session.scalars(
        sa.select(ArtifactRow).where(ArtifactRow.trial_id == trial_id, ArtifactRow.name == name)
    ).one_or_none()
    if row is None:
        row = ArtifactRow(trial_id=trial_id, name=name)
        session.add(row)
    row.content_type = content_type
    row.size = size
    row.sha256 = sha256
    row.path = path
    row.created_at = utcnow()
    session.flush()
    return row


def get_artifact(session: Session, *, trial_id: int, name: str) -> ArtifactRow:
    row = session.scalars(
        sa.select(ArtifactRow).where(ArtifactRow.trial_id == trial_id, ArtifactRow.name == name)
    ).one_or_none()
    if row is None:
        get_trial(session, trial_id=trial_id)
        raise NotFoundError(f"trial {trial_id} has no artifact {name!r}")
    return row


def list_artifacts(session: Session, *, trial_id: int) -> list[ArtifactRow]:
    get_trial(session, trial_id=trial_id)
    return list(
        session.scalars(
            sa.select(ArtifactRow)
            .where(ArtifactRow.trial_id == trial_id)
            .order_by(ArtifactRow.name)
        )
    )


def trial_columns(session: Session, *, study_id: int) -> dict[str, Any]:
    """A study's trials as parallel columns; params of numbers only (what can be plotted)."""
    get_study(session, study_id=study_id)
    rows = session.execute(
        sa.select(TrialRow.number, TrialRow.state, TrialRow.value, TrialRow.params)
        .where(TrialRow.study_id == study_id)
        .order_by(TrialRow.number)
    ).all()
    names: dict[str, None] = {}
    for row in rows:
        for key, value in row.params.items():
            if isinstance(value, int | float) and not isinstance(value, bool):
                names.setdefault(key, None)
    return {
        "number": [row.number for row in rows],
        "state": [row.state for row in rows],
        "value": [row.value for row in rows],
        "params": {name: [row.params.get(name) for row in rows] for name in names},
    }
