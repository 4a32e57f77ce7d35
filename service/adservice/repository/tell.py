"""Repository of tells: finishing a trial, the other half of the ask/tell hot path.

Same conventions as every module of :mod:`adservice.repository` (an open session,
keyword-only arguments, domain errors); a tell returns the trial's schema.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import sqlalchemy as sa
from sqlalchemy.orm import Session

from adclient.objectives import OutcomeError, Outcomes, stored_outcomes
from adclient.schemas import TellRequest, Trial, TrialState
from adservice.errors import ConflictError, ForbiddenError, InvalidError, LeaseLostError
from adservice.models import StudyRow, TrialReportRow, TrialRow, utcnow
from adservice.principals import Principal
from adservice.repository._shared import (
    BEST,
    FINISH,
    SET_OUTCOME,
    WORKER_COUNT,
    counted_value,
    locking,
)
from adservice.repository.leases import check_lease_token
from adservice.repository.studies import check_manager, finish_if_done, get_study
from adservice.repository.transfer import record_transfer_from
from adservice.repository.trials import get_trial


def _same_tell(trial: TrialRow, body: TellRequest, outcomes: Outcomes) -> bool:
    if trial.state != body.state:
        return False
    if body.state == "failed" or (body.state == "pruned" and body.value is None):
        return True
    if body.state == "pruned":
        return _close(trial.value, body.value)
    try:
        told = outcomes.outcome(value=body.value, values=body.values, metrics=body.metrics)
    except OutcomeError:
        return False
    if told.values is not None:
        stored = trial.values or []
        return len(stored) == len(told.values) and all(
            _close(a, b) for a, b in zip(stored, told.values, strict=True)
        )
    return _close(trial.value, told.value)


def _close(a: float | None, b: float | None) -> bool:
    if a is None or b is None:
        return False
    return a == b or math.isclose(a, b, rel_tol=1e-12)


CachedOutcomes = Callable[[int], Outcomes | None]
"""A study's objectives and constraints by its id when a cache has them (the server's
parsed study configs), else None."""


def _outcomes(session: Session, study_id: int, cached: CachedOutcomes | None) -> Outcomes:
    """The study's outcomes from ``cached``, else read from its row."""
    found = cached(study_id) if cached is not None else None
    if found is not None:
        return found
    row = session.execute(
        sa.select(StudyRow.outcomes, StudyRow.direction).where(StudyRow.id == study_id)
    ).one()
    return stored_outcomes(row.outcomes, direction=row.direction)


def tell_trial(
    session: Session,
    *,
    trial_id: int,
    body: TellRequest,
    caller: Principal,
    cached_outcomes: CachedOutcomes | None = None,
) -> Trial:
    """Finish a trial. Repeating an identical tell is harmless; a contradicting one is
    a conflict; a worker that no longer holds the lease is told so; a tell that does not
    fit the study's objectives or constraints is refused (InvalidError, nothing stored).

    The common case is conditional UPDATEs of the trial, of the study's best (which
    changes, and so locks the study row, only for a new best) and of the worker's count:
    a study's counts are those of its trials' states, so a tell writes no counter of the
    study. Only a tell that changes nothing takes the slow path that finds out why, and
    only a study of several objectives or with constraints (``cached_outcomes``, else
    read from the study row) one more that stores the outcome. The UPDATEs are
    ``Prepared`` statements, run in the session's transaction.

    A study whose finished trials reach ``max_trials`` is complete: where writes take
    turns (SQLite) this tell checks so in its transaction; on PostgreSQL the caller runs
    :func:`adservice.repository.studies.finish_if_done` after the commit (two last tells
    at once would each miss the other's uncommitted trial)."""
    now = utcnow()
    complete = body.state != "failed"  # a pruned trial did its job: the worker's jobs_done
    value = body.value
    if body.state == "pruned" and value is None:
        value = _last_reported_value(session, trial_id=trial_id)
    finished = FINISH[body.worker_id is not None, caller.checked].row(
        session,
        {
            "tid": trial_id,
            "wid": body.worker_id,
            "tok": caller.token_id,
            "state": body.state,
            "value": value,
            "message": body.message,
            "metrics": dict(body.metrics),
            "now": now,
        },
    )
    if finished is None:
        return _explain_refused_tell(
            session, trial_id=trial_id, body=body, caller=caller, cached=cached_outcomes
        )
    full = bool(finished["study_full"])
    info = None
    if body.transfer_from is not None:
        info = record_transfer_from(session, trial_id=trial_id, source_id=body.transfer_from)
    if body.state == "complete":
        outcomes = _outcomes(session, finished["study_id"], cached_outcomes)
        if not outcomes.plain or body.values is not None:
            try:
                outcome = outcomes.outcome(
                    value=body.value, values=body.values, metrics=body.metrics
                )
            except OutcomeError as error:
                raise InvalidError(str(error)) from None
            finished = SET_OUTCOME.row(
                session,
                {
                    "tid": trial_id,
                    "value": outcome.value,
                    "values": outcome.values,
                    "feasible": outcome.feasible,
                },
            )
            assert finished is not None
            value = counted_value(outcome)
    if info is not None:  # the returned row was read before the ORM's write
        finished = {**finished, "info": info}
    if body.state == "complete" and value is not None and at_target(finished["info"]):
        # several objectives, infeasible: no value; below a study's target fidelity: no best
        BEST.rows(
            session, [{"sid": finished["study_id"], "tid": trial_id, "value": value, "now": now}]
        )
    if finished["worker_id"] is not None:
        WORKER_COUNT[complete].rows(
            session, [{"wid": finished["worker_id"], "tid": trial_id, "now": now}]
        )
    if full and not locking(session):
        finish_if_done(session, study_id=finished["study_id"])
    return Trial.model_validate(finished)


def at_target(info: dict[str, Any] | None) -> bool:
    """Whether a trial trained to its study's target fidelity (a study without a
    fidelity: always), so that its value may be the study's best."""
    fidelity = (info or {}).get("fidelity")
    return fidelity is None or fidelity >= (info or {}).get("fidelity_max", fidelity)


def _last_reported_value(session: Session, *, trial_id: int) -> float | None:
    """The value at a trial's last reported step: what a pruned tell without a value
    keeps (only that tell runs this query)."""
    return session.scalar(
        sa.select(TrialReportRow.value)
        .where(TrialReportRow.trial_id == trial_id)
        .order_by(TrialReportRow.step.desc())
        .limit(1)
    )


def _explain_refused_tell(
    session: Session,
    *,
    trial_id: int,
    body: TellRequest,
    caller: Principal,
    cached: CachedOutcomes | None,
) -> Trial:
    trial = get_trial(session, trial_id=trial_id)
    if body.worker_id is not None:
        check_lease_token(trial, caller)
    elif caller.checked:
        if trial.worker_id is not None:
            raise ForbiddenError(
                f"trial {trial_id} is leased by worker {trial.worker_id!r}: only the token "
                "that leased it, or an admin, may tell it"
            )
        study = get_study(session, study_id=trial.study_id)
        check_manager(study, caller)
    if trial.state in (TrialState.complete, TrialState.failed, TrialState.pruned):
        if _same_tell(trial, body, _outcomes(session, trial.study_id, cached)):
            return Trial.model_validate(trial, from_attributes=True)
        told = "failed"
        if trial.state != TrialState.failed:
            told = f"values {trial.values}" if trial.values else f"value {trial.value}"
        raise ConflictError(f"trial {trial_id} is already {trial.state} ({told})")
    raise LeaseLostError(f"worker {body.worker_id!r} does not hold the lease of trial {trial_id}")
