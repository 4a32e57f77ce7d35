"""Repository of studies: create, read, count and stop them, check who manages one, and
read a study's trials as a proposer's history.

Same conventions as every module of :mod:`adservice.repository` (an open session,
keyword-only arguments, domain errors, rows out).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from datetime import datetime, timedelta
from typing import Any

import numpy as np
import sqlalchemy as sa
from sqlalchemy.orm import Session

from adclient.objectives import OutcomeError, Outcomes, outcomes_json
from adclient.schemas import StudyCreate, TrialState
from adservice import principals
from adservice.errors import NotFoundError
from adservice.models import StudyRow, TrialRow, utcnow
from adservice.principals import Principal
from adservice.repository._shared import ADD_FALLBACKS, CLEAR_FALLBACK_REASON, locking


def create_study(
    session: Session,
    *,
    body: StudyCreate,
    representation: dict[str, Any] | None,
    owner: Principal,
) -> StudyRow:
    outcomes = body.outcomes()
    row = StudyRow(
        owner_token_id=owner.token_id,
        created_by=owner.name or None,
        name=body.name,
        direction=outcomes.directions[0].value,
        outcomes=outcomes_json(outcomes),
        state="running",
        space=body.space.model_dump(mode="json"),
        proposer=body.proposer.model_dump(mode="json"),
        pruner=body.pruner.model_dump(mode="json"),
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
    if for_update and locking(session):
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


def last_finished_at(session: Session, *, study_id: int) -> datetime | None:
    """When the study's latest trial finished (None: none has)."""
    return session.scalar(
        sa.select(sa.func.max(TrialRow.finished_at)).where(TrialRow.study_id == study_id)
    )


def stop_study(session: Session, *, study_id: int, caller: Principal) -> StudyRow:
    """Stop proposing and leasing; queued trials are dropped as failed."""
    study = get_study(session, study_id=study_id, for_update=True)
    check_manager(study, caller)
    if study.state != "running":
        return study
    now = utcnow()
    session.execute(
        sa.update(TrialRow)
        .where(TrialRow.study_id == study_id, TrialRow.state == TrialState.queued)
        .values(state=TrialState.failed, message="study stopped", finished_at=now)
    )
    study.state = "stopped"
    study.updated_at = now
    return study


def record_proposal_failure(
    session: Session,
    *,
    study_id: int,
    error: str,
    backoff_seconds: float,
    max_backoff_seconds: float,
) -> StudyRow:
    """One more failed proposal of the study in a row: why, and when leases may try it
    again (``backoff_seconds``, doubled with each failure in a row, at most
    ``max_backoff_seconds``)."""
    study = get_study(session, study_id=study_id, for_update=True)
    study.proposal_failures = (study.proposal_failures or 0) + 1
    study.proposal_error = error
    delay = min(max_backoff_seconds, backoff_seconds * 2.0 ** min(study.proposal_failures - 1, 64))
    study.proposal_retry_at = utcnow() + timedelta(seconds=delay)
    return study


def record_fallbacks(session: Session, *, study_id: int, count: int, reason: str | None) -> None:
    """An ask's model phase ran: ``count`` of its candidates fell back for ``reason``
    (0 and None: none did, which clears the study's reason)."""
    if count:
        ADD_FALLBACKS.rows(session, [{"sid": study_id, "count": count, "reason": reason}])
    else:
        CLEAR_FALLBACK_REASON.rows(session, [{"sid": study_id}])


def check_manager(study: StudyRow, caller: Principal) -> None:
    """Asking, telling, stopping or deleting a study is for its owner (or an admin)."""
    principals.check_manager(
        caller, study_id=study.id, owner_token_id=study.owner_token_id, owner_name=study.created_by
    )


FINISHED = (TrialState.complete, TrialState.failed, TrialState.pruned)
"""The states a trial ends in: a study's trials in these count towards ``max_trials``."""


def finish_study_if_done(session: Session, study: StudyRow) -> None:
    """Mark a running study complete once its finished trials reach ``max_trials``.

    The count is of the trials table (a study keeps no counters of its own), so the
    caller holds the study's row lock, taken before this count's statement: on
    PostgreSQL that statement's snapshot then holds every finish committed before the
    lock, and a finish committed after it checks again (:func:`finish_if_done`)."""
    if study.state != "running" or study.max_trials is None or study.n_trials < study.max_trials:
        return  # a trial not yet numbered cannot have finished
    finished = session.scalar(
        sa.select(sa.func.count())
        .select_from(TrialRow)
        .where(TrialRow.study_id == study.id, TrialRow.state.in_(FINISHED))
    )
    if (finished or 0) >= study.max_trials:
        study.state = "complete"
        study.updated_at = utcnow()


_FULL = (
    sa.select(StudyRow)
    .where(
        StudyRow.id == sa.bindparam("sid"),
        StudyRow.state == "running",
        StudyRow.max_trials.is_not(None),
        StudyRow.n_trials >= StudyRow.max_trials,
    )
    .execution_options(populate_existing=True)
)


def finish_if_done(session: Session, *, study_id: int) -> None:
    """:func:`finish_study_if_done` for a study whose trials may all be numbered, its
    row locked first; one read that locks nothing for a study with room left (or none
    to finish). A tell runs this after its commit on PostgreSQL: of two last tells
    committing at once, each unseen by the other's statements, the later to take the
    lock sees both."""
    query = _FULL.with_for_update() if locking(session) else _FULL
    study = session.scalars(query, {"sid": study_id}).one_or_none()
    if study is not None:
        finish_study_if_done(session, study)


# --- history for proposers ------------------------------------------------------------


@dataclass(frozen=True)
class History:
    """A study's trials as arrays, values as stored (not yet oriented). For a study of
    several objectives or with constraints: ``values`` (n x m, each observed trial's
    objective values; ``y`` is its first column) and ``slacks`` (n x c, <= 0 where a
    constraint holds)."""

    X: np.ndarray
    y: np.ndarray
    failed: np.ndarray
    pending: np.ndarray
    values: np.ndarray | None = None
    slacks: np.ndarray | None = None
    fidelities: np.ndarray | None = None
    """A study with a fidelity: the train_steps of each row of ``X`` (its trial's
    ``info.fidelity``, else the target), then of each row of ``pending``."""
    pending_fidelities: np.ndarray | None = None


def study_history(
    session: Session,
    *,
    study_id: int,
    dim: int,
    pruned_as_observed: bool = True,
    outcomes: Outcomes | None = None,
    fidelity_max: int | None = None,
) -> History:
    """``pruned_as_observed``: a pruned trial with a value (its last report) counts as an
    observation of that value; otherwise it is left out (docs/pruning.md). A study of
    several objectives observes its complete trials only (a pruned one has no values);
    an infeasible trial is observed, with its slacks. ``fidelity_max``: a study's target
    fidelity, where it has one (``History.fidelities``, from each trial's info)."""
    outcomes = outcomes or Outcomes()
    columns: list[Any] = [TrialRow.state, TrialRow.vector, TrialRow.value]
    if not outcomes.plain:
        columns += [TrialRow.values, TrialRow.metrics]
    if fidelity_max is not None:
        columns.append(TrialRow.info)
    rows = session.execute(
        sa.select(*columns).where(TrialRow.study_id == study_id).order_by(TrialRow.number)
    ).all()
    observed = {TrialState.complete, TrialState.pruned if pruned_as_observed else "complete"}
    if outcomes.multi:
        observed = {TrialState.complete}
    empty = np.zeros((0, dim))

    def stack(vectors: list[list[float]]) -> np.ndarray:
        return np.asarray(vectors, dtype=np.float64).reshape(-1, dim) if vectors else empty

    def point(row: Any) -> list[float] | None:
        if outcomes.multi:
            return list(row.values) if row.values else None
        return None if row.value is None else [row.value]

    seen = [(row, p) for row in rows if row.state in observed and (p := point(row)) is not None]
    values = np.asarray([p for _, p in seen], dtype=np.float64).reshape(-1, outcomes.count)
    slacks = None
    if outcomes.constraints:
        slacks = np.asarray(
            [_slacks(outcomes, row, p) for row, p in seen], dtype=np.float64
        ).reshape(-1, len(outcomes.constraints))
    history = History(
        X=stack([row.vector for row, _ in seen]),
        y=values[:, 0].copy(),
        failed=stack([row.vector for row in rows if row.state == TrialState.failed]),
        pending=stack(
            [row.vector for row in rows if row.state in (TrialState.queued, TrialState.running)]
        ),
        values=values if outcomes.multi else None,
        slacks=slacks,
    )
    if fidelity_max is None:
        return history

    def steps(row: Any) -> float:
        return float((row.info or {}).get("fidelity") or fidelity_max)

    running = (TrialState.queued, TrialState.running)
    return replace(
        history,
        fidelities=np.asarray([steps(row) for row, _ in seen], dtype=np.float64),
        pending_fidelities=np.asarray(
            [steps(row) for row in rows if row.state in running], dtype=np.float64
        ),
    )


def _slacks(outcomes: Outcomes, row: Any, values: list[float]) -> list[float]:
    """A trial's constraint slacks; a pruned trial (no metrics told) counts as breaking
    none, as its value alone is what the proposer learns from it."""
    try:
        return outcomes.slacks(row.metrics or {}, values)
    except OutcomeError:
        return [0.0] * len(outcomes.constraints)
