"""Repository of leases and workers: a worker leases a managed study's queued trial,
keeps it with heartbeats or gives it back, and an expired lease sends the trial back to
the queue; the workers seen.

Same conventions as every module of :mod:`adservice.repository` (an open session,
keyword-only arguments, domain errors, rows out).
"""

from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime, timedelta

import sqlalchemy as sa
from sqlalchemy.orm import Session

from adclient.schemas import TrialState
from adservice.errors import ForbiddenError, LeaseLostError
from adservice.models import StudyRow, TrialRow, WorkerRow, utcnow
from adservice.principals import Principal
from adservice.repository._shared import locking, served_changed, touch_worker
from adservice.repository.quotas import within_quota
from adservice.repository.studies import finish_study_if_done, get_study
from adservice.repository.trials import get_trial


def expire_leases(session: Session, *, now: datetime | None = None) -> int:
    """Send trials whose lease ran out back to the queue, or fail them after
    ``max_attempts``. Returns how many leases expired."""
    now = now or utcnow()
    query = (
        sa.select(TrialRow, StudyRow)
        .join(StudyRow, StudyRow.id == TrialRow.study_id)
        .where(TrialRow.state == TrialState.running, TrialRow.lease_expires_at < now)
    )
    if locking(session):
        query = query.with_for_update(of=TrialRow, skip_locked=True)
    expired = session.execute(query).all()
    if expired and locking(session):
        # Lock the studies (in id order, after the trials, as a tell does) before a study
        # counts its finished trials (finish_study_if_done), and reload them.
        session.execute(
            sa.select(StudyRow)
            .where(StudyRow.id.in_({study.id for _, study in expired}))
            .order_by(StudyRow.id)
            .with_for_update()
            .execution_options(populate_existing=True)
        ).all()
    for trial, study in expired:
        worker = session.get(WorkerRow, trial.worker_id) if trial.worker_id else None
        if worker is not None and worker.current_trial_id == trial.id:
            worker.current_trial_id = None
        trial.lease_expires_at = None
        if trial.attempts >= study.max_attempts:
            trial.state = TrialState.failed
            trial.message = f"lease expired on each of {trial.attempts} attempts"
            trial.finished_at = now
            if worker is not None:
                worker.jobs_failed = WorkerRow.jobs_failed + 1  # in SQL: the row is not locked
            finish_study_if_done(session, study)
        else:
            trial.state = TrialState.queued
            trial.worker_id = None
            trial.lease_token_id = None
        study.updated_at = now
    return len(expired)


def _leasable(
    tasks: Sequence[str] | None,
    learners: Sequence[str] | None,
    owner: int | None,
    storage_quota: int | None,
) -> tuple[list[sa.ColumnElement[bool]], dict[str, int]]:
    """Where-clauses for managed studies, and the parameters to execute them with; with
    ``tasks`` (``learners``) only those whose task (its learner) has one of these names;
    with ``owner`` only that token's studies (a user's lease: ``Principal.leased_owner``);
    with ``storage_quota`` only those whose owner stores less than that many bytes."""
    where: list[sa.ColumnElement[bool]] = [StudyRow.task.is_not(None)]
    if tasks is not None:
        where.append(StudyRow.task["name"].as_string().in_(list(tasks)))
    if learners is not None:
        where.append(StudyRow.task["learner"].as_string().in_(list(learners)))
    if owner is not None:
        where.append(StudyRow.owner_token_id == owner)
    within, params = within_quota(storage_quota)
    return where + within, params


def _not_backing_off(now: datetime) -> sa.ColumnElement[bool]:
    """Studies whose proposals (or jobs) have not failed, or whose backoff is over."""
    return sa.or_(StudyRow.proposal_retry_at.is_(None), StudyRow.proposal_retry_at <= now)


def lease_queued_trial(
    session: Session,
    *,
    worker_id: str,
    lease_token_id: int | None,
    lease_seconds: float,
    tasks: Sequence[str] | None = None,
    learners: Sequence[str] | None = None,
    owner: int | None = None,
    storage_quota: int | None = None,
) -> TrialRow | None:
    """Lease the oldest queued trial of a running managed study (of one of ``tasks``
    and ``learners``, of ``owner``'s when given, whose owner is within
    ``storage_quota``) that is not backing off after a failure (``proposal_retry_at``).

    With none queued, only a new worker, or one that now serves other tasks or learners,
    is written (so the transaction commits without a write when nothing changed): the
    caller records the worker as seen, by the proposal that leases it a trial or by
    :func:`record_idle_worker`."""
    now = utcnow()
    expire_leases(session, now=now)
    leasable, params = _leasable(tasks, learners, owner, storage_quota)
    query = (
        sa.select(TrialRow)
        .join(StudyRow, StudyRow.id == TrialRow.study_id)
        .where(
            TrialRow.state == TrialState.queued,
            StudyRow.state == "running",
            *leasable,
            _not_backing_off(now),
        )
        .order_by(TrialRow.id)
        .limit(1)
    )
    if locking(session):
        query = query.with_for_update(of=TrialRow, skip_locked=True)
    trial = session.scalars(query, params).one_or_none()
    if trial is None:
        if served_changed(session, worker_id=worker_id, tasks=tasks, learners=learners):
            record_idle_worker(session, worker_id=worker_id, tasks=tasks, learners=learners)
        return None
    trial.state = TrialState.running
    trial.worker_id = worker_id
    trial.lease_token_id = lease_token_id
    trial.attempts += 1
    trial.leases += 1
    trial.started_at = now
    trial.heartbeat_at = now
    trial.lease_expires_at = now + timedelta(seconds=lease_seconds)
    touch_worker(
        session,
        worker_id=worker_id,
        now=now,
        current_trial_id=trial.id,
        tasks=tasks,
        learners=learners,
    )
    return trial


def record_idle_worker(
    session: Session,
    *,
    worker_id: str,
    tasks: Sequence[str] | None,
    learners: Sequence[str] | None,
) -> None:
    """A lease that found no work: the worker seen now, holding no trial, serving
    ``tasks`` and ``learners``."""
    touch_worker(
        session,
        worker_id=worker_id,
        now=utcnow(),
        current_trial_id=None,
        tasks=tasks,
        learners=learners,
    )


def studies_wanting_trials(
    session: Session,
    *,
    tasks: Sequence[str] | None = None,
    learners: Sequence[str] | None = None,
    owner: int | None = None,
    storage_quota: int | None = None,
) -> list[int]:
    """Running managed studies (of one of ``tasks`` and ``learners``, of ``owner``'s
    when given, whose owner is within ``storage_quota``) with room for a trial, oldest
    first; a study whose proposals failed is left out until its ``proposal_retry_at``."""
    leasable, params = _leasable(tasks, learners, owner, storage_quota)
    query = (
        sa.select(StudyRow.id)
        .where(
            StudyRow.state == "running",
            *leasable,
            StudyRow.n_trials < StudyRow.max_trials,
            _not_backing_off(utcnow()),
        )
        .order_by(StudyRow.id)
    )
    return list(session.scalars(query, params))


def check_lease_token(trial: TrialRow, caller: Principal) -> None:
    """A trial's lease belongs to the token that took it: anyone else is forbidden."""
    if (
        caller.checked
        and trial.lease_token_id is not None
        and trial.lease_token_id != caller.token_id
    ):
        raise ForbiddenError(
            f"trial {trial.id} is leased by another token: only the token that leased it, "
            "or an admin, may act on it"
        )


def held_trial(
    session: Session, *, trial_id: int, worker_id: str | None, caller: Principal
) -> TrialRow:
    """The running trial ``worker_id`` holds under ``caller``'s token, locked for update;
    403 for another token, 409 when the lease is lost. An admin may name no worker."""
    trial = get_trial(session, trial_id=trial_id, for_update=True)
    check_lease_token(trial, caller)
    if worker_id is None and not caller.is_admin:
        raise ForbiddenError(f"give the worker_id that holds trial {trial_id}")
    if trial.state != TrialState.running or (
        worker_id is not None and trial.worker_id != worker_id
    ):
        raise LeaseLostError(f"worker {worker_id!r} does not hold the lease of trial {trial_id}")
    return trial


def heartbeat(
    session: Session, *, trial_id: int, worker_id: str, lease_seconds: float, caller: Principal
) -> TrialRow:
    trial = held_trial(session, trial_id=trial_id, worker_id=worker_id, caller=caller)
    now = utcnow()
    trial.heartbeat_at = now
    trial.lease_expires_at = now + timedelta(seconds=lease_seconds)
    touch_worker(session, worker_id=worker_id, now=now, current_trial_id=trial.id)
    return trial


def release_lease(
    session: Session, *, trial_id: int, worker_id: str | None, caller: Principal
) -> TrialRow:
    """Give a held trial back to the queue now (a worker shutting down mid-job, or an
    admin naming no worker), so it need not wait for the lease to expire. The attempt is
    not counted against ``max_attempts``: the design did not fail, the worker left."""
    trial = held_trial(session, trial_id=trial_id, worker_id=worker_id, caller=caller)
    holder = trial.worker_id
    trial.state = TrialState.queued
    trial.worker_id = None
    trial.lease_token_id = None
    trial.lease_expires_at = None
    trial.attempts -= 1
    if holder is not None:
        touch_worker(session, worker_id=holder, now=utcnow(), current_trial_id=None)
    return trial


def list_workers(
    session: Session,
    *,
    study_id: int | None = None,
    seen_since: datetime | None = None,
    offset: int = 0,
    limit: int | None = None,
) -> list[WorkerRow]:
    """All workers, or those that ever held a trial of ``study_id``, newest first; with
    ``seen_since`` only those seen then or later; ``offset`` and ``limit`` page them."""
    query = (
        sa.select(WorkerRow)
        .order_by(WorkerRow.last_seen_at.desc(), WorkerRow.worker_id)
        .offset(offset)
        .limit(limit)
    )
    if study_id is not None:
        get_study(session, study_id=study_id)
        held = sa.select(TrialRow.worker_id).where(TrialRow.study_id == study_id).distinct()
        query = query.where(WorkerRow.worker_id.in_(held))
    if seen_since is not None:
        query = query.where(WorkerRow.last_seen_at >= seen_since)
    return list(session.scalars(query))
