"""Repository of ASHA promotion: pause a trial with its checkpoint, promote the paused
trials that qualify at their rung, end the ones left when the study's budget is spent.

Same conventions as every module of :mod:`adservice.repository` (an open session,
keyword-only arguments, domain errors, rows out). Nothing here is on the ask/tell hot
path: pausing and promoting happen on reports, settling when a worker asks for work. A
promoted trial resumes only from the checkpoint a worker uploaded under the lease that
paused it (:func:`resume_point`).
"""

from __future__ import annotations

import functools
from typing import Any, cast

import numpy as np
import sqlalchemy as sa
from sqlalchemy.orm import Session, aliased

from adclient.pruning import AshaOptions, Checkpoint, PauseRequest, PrunerConfig
from adclient.schemas import Trial, TrialState
from adservice.errors import ConflictError, InvalidError
from adservice.models import ArtifactRow, StudyRow, TrialRow, WorkerRow, utcnow
from adservice.principals import Principal
from adservice.pruners.asha import qualifies, rung_values, waiting_rung
from adservice.pruners.base import Curve
from adservice.repository.artifacts import trusted_checkpoint
from adservice.repository.leases import check_lease_token, held_trial
from adservice.repository.reports import curves_by_trial
from adservice.repository.studies import History, finish_if_done, finish_study_if_done, get_study
from adservice.repository.transfer import record_transfer_from
from adservice.repository.trials import get_trial


def asha_promotion(pruner: dict[str, Any] | PrunerConfig | None) -> AshaOptions | None:
    """The study's ASHA options when it pauses and promotes trials, else None."""
    config = pruner if isinstance(pruner, PrunerConfig) else PrunerConfig.model_validate(pruner)
    options = config.parsed()
    return options if isinstance(options, AshaOptions) and options.promotion else None


def _same_pause(trial: TrialRow, body: PauseRequest) -> bool:
    checkpoint = trial.checkpoint or {}
    return (
        trial.state == TrialState.paused
        and checkpoint.get("step") == body.step
        and checkpoint.get("artifact") == body.checkpoint
    )


def pause_trial(
    session: Session, *, trial_id: int, body: PauseRequest, caller: Principal
) -> TrialRow:
    """The lease holder pauses its trial at ``body.step`` with the checkpoint artifact it
    uploaded: the trial leaves its lease and waits at its rung (promoted at once if it
    already qualifies there). A repeat is harmless; 403 for another token, 409 for a
    lost lease, a study that does not pause trials or a missing checkpoint, 422 for a
    step below the first rung. The checkpoint must be uploaded under this lease."""
    trial = get_trial(session, trial_id=trial_id, for_update=True)
    if _same_pause(trial, body):
        check_lease_token(trial, caller)
        return trial
    holder = body.worker_id
    trial = held_trial(session, trial_id=trial_id, worker_id=holder, caller=caller)
    study = get_study(session, study_id=trial.study_id, for_update=True)
    options = asha_promotion(study.pruner)
    if options is None:
        raise ConflictError(
            f"study {study.id}'s pruner does not pause trials (asha with promotion: true "
            f"does): tell trial {trial_id} pruned instead"
        )
    rung = waiting_rung(options, body.step)
    if rung is None:
        raise InvalidError(
            f"step: {body.step} is below study {study.id}'s first ASHA rung "
            f"({options.min_resource * options.reduction_factor**options.min_early_stopping_rate}"
            "): a trial pauses at a rung"
        )
    uploaded = session.scalar(
        sa.select(ArtifactRow.attempt).where(
            ArtifactRow.trial_id == trial_id, ArtifactRow.name == body.checkpoint
        )
    )
    if uploaded is None or uploaded != trial.leases:
        raise ConflictError(
            f"trial {trial_id} has no artifact {body.checkpoint!r} uploaded under this lease: "
            "upload the checkpoint, then pause"
        )
    maximize = study.direction == "maximize"
    curves = curves_by_trial(session, study_id=study.id, maximize=maximize)
    value = body.value
    if value is None and trial_id in curves:
        value = (1.0 if maximize else -1.0) * float(curves[trial_id].values[-1])
    now = utcnow()
    trial.state = TrialState.paused
    trial.value = value
    trial.metrics = dict(body.metrics)
    trial.checkpoint = Checkpoint(
        artifact=body.checkpoint,
        step=body.step,
        rung=rung,
        metrics=body.metrics,
        lease=trial.leases,
        budget=body.budget,
    ).model_dump()
    trial.worker_id = None
    trial.lease_token_id = None
    trial.lease_expires_at = None
    trial.attempts -= 1  # the attempt did not fail: it ran to its rung
    if body.transfer_from is not None:
        record_transfer_from(session, trial_id=trial_id, source_id=body.transfer_from)
    worker = session.get(WorkerRow, holder)
    if worker is not None:
        worker.last_seen_at = now
        worker.jobs_done = WorkerRow.jobs_done + 1
        if worker.current_trial_id == trial_id:
            worker.current_trial_id = None
    study.updated_at = now
    session.flush()
    promote(session, study_id=study.id, options=options, curves=curves)
    settle(session, study=study)
    return trial


def resume_point(session: Session, *, trial: Trial) -> Checkpoint | None:
    """Where a promoted trial's job resumes: its checkpoint while the artifact is still
    the one a worker uploaded under the lease that paused it; else None (a user token's
    or an owner's upload, one replaced since, or a pause recorded before uploaders
    were), and the job trains from scratch."""
    checkpoint = trial.checkpoint
    if checkpoint is None or checkpoint.lease is None:
        return None
    found = session.scalar(
        sa.select(ArtifactRow.id).where(
            ArtifactRow.trial_id == trial.id,
            ArtifactRow.name == checkpoint.artifact,
            trusted_checkpoint(checkpoint.lease),
        )
    )
    return checkpoint if found is not None else None


def promote(
    session: Session, *, study_id: int, options: AshaOptions, curves: dict[int, Curve]
) -> list[int]:
    """Queue again each paused trial of a running study that now qualifies at its rung
    (``curves``: the study's, by trial); returns their ids."""
    paused = session.scalars(
        sa.select(TrialRow)
        .join(StudyRow, StudyRow.id == TrialRow.study_id)
        .where(
            TrialRow.study_id == study_id,
            TrialRow.state == TrialState.paused,
            StudyRow.state == "running",
        )
        .order_by(TrialRow.id)
    ).all()
    promoted = []
    for trial in paused:
        rung = int((trial.checkpoint or {}).get("rung", 0))
        curve = curves.get(trial.id)
        value = curve.first_at_or_after(rung) if curve is not None else None
        if value is not None and qualifies(options, value, rung_values(rung, curves.values())):
            trial.state = TrialState.queued
            promoted.append(trial.id)
    return promoted


_ACTIVE = (TrialState.queued.value, TrialState.running.value)


@functools.cache
def _spent() -> sa.ColumnElement[bool]:
    """A study whose paused trials can no longer be promoted: stopped, or out of new
    trials with none queued or running (nothing left to report at a rung). Built once
    (an expression is immutable; every lease's statement reuses it): building it took
    1.5 ms, most of a lease's settling."""
    other = aliased(TrialRow)
    active = (
        sa.select(other.id)
        .where(other.study_id == StudyRow.id, other.state.in_(_ACTIVE))
        .correlate(StudyRow)
        .exists()
    )
    full = sa.and_(StudyRow.max_trials.is_not(None), StudyRow.n_trials >= StudyRow.max_trials)
    return sa.or_(StudyRow.state != "running", sa.and_(full, ~active))


def settle(session: Session, *, study: StudyRow) -> int:
    """End a spent study's paused trials as pruned, each with its value at the pause;
    returns how many."""
    if not session.scalar(sa.select(_spent()).select_from(StudyRow).where(StudyRow.id == study.id)):
        return 0
    now = utcnow()
    ended = cast(
        sa.CursorResult[Any],
        session.execute(
            sa.update(TrialRow)
            .where(TrialRow.study_id == study.id, TrialRow.state == TrialState.paused)
            .values(
                state=TrialState.pruned,
                finished_at=now,
                message="paused at a rung when the study's budget was spent",
            )
            .execution_options(synchronize_session="fetch")
        ),
    ).rowcount
    if ended:
        study.updated_at = now
        finish_study_if_done(session, study)
    return ended or 0


def settle_spent_studies(session: Session) -> int:
    """:func:`settle` every spent study with paused trials (one indexed query when there
    are none); returns how many trials ended."""
    study_ids = session.scalars(
        sa.select(TrialRow.study_id)
        .join(StudyRow, StudyRow.id == TrialRow.study_id)
        .where(TrialRow.state == TrialState.paused, _spent())
        .distinct()
    ).all()
    return sum(
        settle(session, study=get_study(session, study_id=study_id, for_update=True))
        for study_id in study_ids
    )


def finish_done_studies(session: Session) -> int:
    """Finish every running study whose trials are all numbered and none is queued,
    running or paused: on PostgreSQL a tell checks its study's end after its commit, and
    a server that stopped in between left it running (the lease sweep runs this). One
    indexed query when there are none; returns how many were finished."""
    study_ids = session.scalars(
        sa.select(StudyRow.id).where(StudyRow.state == "running", _spent()).order_by(StudyRow.id)
    ).all()
    finished = 0
    for study_id in study_ids:
        finish_if_done(session, study_id=study_id)
        finished += get_study(session, study_id=study_id).state != "running"
    return finished


def with_paused(session: Session, *, history: History, study_id: int, dim: int) -> History:
    """``history`` with the study's paused trials observed at their pause values, as
    pruned ones are (docs/pruning.md): once, never also pending or complete."""
    rows = session.execute(
        sa.select(TrialRow.vector, TrialRow.value).where(
            TrialRow.study_id == study_id,
            TrialRow.state == TrialState.paused,
            TrialRow.value.is_not(None),
        )
    ).all()
    if not rows:
        return history
    vectors = np.asarray([vector for vector, _ in rows], dtype=np.float64).reshape(-1, dim)
    values = np.asarray([value for _, value in rows], dtype=np.float64)
    slacks = history.slacks
    if slacks is not None:  # a paused trial was told no metrics: it breaks no constraint
        slacks = np.vstack([slacks, np.zeros((len(values), slacks.shape[1]))])
    return History(
        X=np.vstack([history.X, vectors]),
        y=np.concatenate([history.y, values]),
        failed=history.failed,
        pending=history.pending,
        slacks=slacks,
    )
