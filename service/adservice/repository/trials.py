"""Repository of trials: new ones (asked, enqueued or added), reading them, and the
checks an ask makes (room in the study, trials already there).

Same conventions as every module of :mod:`adservice.repository` (an open session,
keyword-only arguments, domain errors, rows out). Finishing a trial is
:mod:`adservice.repository.tell`.
"""

from __future__ import annotations

from collections.abc import Sequence
from datetime import datetime, timedelta
from typing import Any, NamedTuple, cast

import sqlalchemy as sa
from sqlalchemy.orm import Session

from adclient.objectives import Outcome, pareto_front, stored_outcomes
from adclient.schemas import Trial, TrialAdd, TrialState
from adservice.db import Prepared
from adservice.errors import ConflictError, NotFoundError
from adservice.models import StudyRow, TrialRow, utcnow
from adservice.repository._shared import (
    BEST,
    CLAIM_QUEUED,
    INSERT_TRIALS,
    RESERVE,
    RESERVE_PROPOSING,
    counted_value,
    locking,
    touch_worker,
)
from adservice.repository.studies import finish_if_done, get_study

TRIAL_ORDERS = {
    "number": TrialRow.number,
    "value": TrialRow.value,
    "state": TrialRow.state,
    "created_at": TrialRow.created_at,
    "finished_at": TrialRow.finished_at,
    "worker_id": TrialRow.worker_id,
    "attempts": TrialRow.attempts,
}
PARAM_ORDER_PREFIX = "param:"
"""``order_by="param:NAME"`` sorts by a param's value (numbers by value, then text)."""


def _trial_order(session: Session, order_by: str) -> sa.SQLColumnExpression[Any]:
    """The sort key for ``order_by``: a column, ``duration`` (seconds from start to
    finish) or ``param:NAME``; each database spells the last two its own way. Names are
    checked by the route (a param name's pattern keeps the JSON path literal safe)."""
    postgres = session.get_bind().dialect.name == "postgresql"
    if order_by == "duration":
        if postgres:
            return sa.extract("epoch", TrialRow.finished_at - TrialRow.started_at)
        return sa.func.julianday(TrialRow.finished_at) - sa.func.julianday(TrialRow.started_at)
    if order_by.startswith(PARAM_ORDER_PREFIX):
        name = order_by.removeprefix(PARAM_ORDER_PREFIX)
        if postgres:
            from sqlalchemy.dialects.postgresql import JSONB

            return sa.cast(TrialRow.params, JSONB).op("->")(name)
        return sa.func.json_extract(TrialRow.params, f'$."{name}"')
    return TRIAL_ORDERS[order_by]


def reserve_numbers(session: Session, *, study_id: int, count: int) -> int:
    """Claim the next ``count`` trial numbers of a running study with room; returns the
    first. One conditional UPDATE: it checks, reserves and (on PostgreSQL) row-locks."""
    return _first_number(session, RESERVE, study_id=study_id, count=count)["first"]


class Reserved(NamedTuple):
    first: int
    """The first reserved trial number."""
    fallback_reason: str | None
    """The study's recorded reason for its last proposal's fallbacks."""


def reserve_for_proposal(session: Session, *, study_id: int, count: int) -> Reserved:
    """:func:`reserve_numbers` for a proposal, in the same one UPDATE of the study row:
    its recorded proposal failures cleared (the proposal succeeded, or its transaction
    rolls back) and the fallback reason it holds returned, so an ask clears that only
    when there is one."""
    row = _first_number(session, RESERVE_PROPOSING, study_id=study_id, count=count)
    return Reserved(row["first"], row["proposal_fallback_reason"])


def _first_number(
    session: Session, statement: Prepared, *, study_id: int, count: int
) -> dict[str, Any]:
    reserved = statement.row(session, {"sid": study_id, "count": count, "now": utcnow()})
    if reserved is None:
        check_room(get_study(session, study_id=study_id), count=count)
        raise ConflictError(f"study {study_id} takes no new trials")  # changed meanwhile
    return {**reserved, "first": int(reserved["n_trials"]) - count}


def _new_trial(
    *,
    study_id: int,
    number: int,
    vector: Sequence[float],
    params: dict[str, Any],
    now: datetime,
    **columns: Any,
) -> dict[str, Any]:
    """A trials row to insert, naming every column the insert sets (one compiled
    statement for all), with ``columns`` over a queued trial's defaults."""
    return {
        "study_id": study_id,
        "number": number,
        "state": TrialState.queued.value,
        "vector": [float(x) for x in vector],
        "params": params,
        "value": None,
        "values": None,
        "feasible": None,
        "message": None,
        "metrics": {},
        "info": {},
        "worker_id": None,
        "attempts": 0,
        "leases": 0,
        "created_at": now,
        "started_at": None,
        "finished_at": None,
        "heartbeat_at": None,
        "lease_expires_at": None,
        "lease_token_id": None,
    } | columns


def insert_trials(
    session: Session,
    *,
    study_id: int,
    first_number: int,
    vectors: Sequence[Sequence[float]],
    params: Sequence[dict[str, Any]],
    infos: Sequence[dict[str, Any]],
    worker_id: str | None = None,
    lease_token_id: int | None = None,
    lease_seconds: float = 60.0,
    record_worker: bool = True,
) -> list[Trial]:
    """New trials numbered from ``first_number`` (see :func:`reserve_numbers`), in state
    ``running`` and leased to ``worker_id`` (and its token) when given, the worker
    recorded as seen holding the first (unless ``record_worker`` is False: the caller
    does so with :func:`record_leased`). A ``Prepared`` statement in the session's
    transaction: no ORM bookkeeping per trial."""
    now = utcnow()
    lease: dict[str, Any] = {}
    if worker_id:
        lease = {
            "worker_id": worker_id,
            "attempts": 1,
            "leases": 1,
            "heartbeat_at": now,
            "lease_expires_at": now + timedelta(seconds=lease_seconds),
            "lease_token_id": lease_token_id,
        }
    values = [
        _new_trial(
            study_id=study_id,
            number=first_number + offset,
            vector=vector,
            params=param,
            now=now,
            state=TrialState.running.value,
            info=info,
            started_at=now,
            **lease,
        )
        for offset, (vector, param, info) in enumerate(zip(vectors, params, infos, strict=True))
    ]
    ids = [row["id"] for row in INSERT_TRIALS.rows(session, values)]
    if worker_id and record_worker:
        touch_worker(session, worker_id=worker_id, now=now, current_trial_id=ids[0])
    return [
        Trial.model_validate({"id": trial_id, **row})
        for trial_id, row in zip(ids, values, strict=True)
    ]


def record_leased(session: Session, *, worker_id: str, trial_id: int) -> None:
    """The worker seen now, holding the trial just leased to it (:func:`insert_trials`
    with ``record_worker`` False)."""
    touch_worker(session, worker_id=worker_id, now=utcnow(), current_trial_id=trial_id)


def commit_without_flush(session: Session) -> None:
    """On PostgreSQL, this transaction's commit returns before its WAL reaches the disk
    (``synchronous_commit`` off for it alone): its row locks are released without that
    wait. Durable once any later transaction's commit waits for its own flush (WAL is
    flushed in order); until then a crash of the database may undo it, whole. The
    caller commits such a transaction before telling anyone of it."""
    if locking(session):
        session.execute(sa.text("SET LOCAL synchronous_commit TO OFF"))


def claim_queued(session: Session, *, study_id: int, count: int) -> list[Trial]:
    """Up to ``count`` of the study's queued trials, oldest first, now running: an ask
    hands out enqueued trials before proposing (one indexed lookup when none wait; on
    PostgreSQL concurrent asks skip each other's rows)."""
    rows = CLAIM_QUEUED.rows(session, [{"sid": study_id, "count": count, "now": utcnow()}])
    return [Trial.model_validate(row) for row in sorted(rows, key=lambda row: row["number"])]


def count_queued(session: Session, *, study_id: int) -> int:
    return (
        session.scalar(
            sa.select(sa.func.count())
            .select_from(TrialRow)
            .where(TrialRow.study_id == study_id, TrialRow.state == TrialState.queued)
        )
        or 0
    )


def add_trials(
    session: Session,
    *,
    study_id: int,
    first_number: int,
    vectors: Sequence[Sequence[float]],
    params: Sequence[dict[str, Any]],
    adds: Sequence[TrialAdd],
    outcomes: Sequence[Outcome | None],
) -> list[Trial]:
    """Trials a user hands over, numbered from ``first_number``: queued ones wait for an
    ask or a lease; finished ones count in the study's counts and best, and towards its
    ``max_trials``, as a tell of them would (``info.source`` says which: ``enqueued`` or
    ``added``). ``outcomes``: a complete one's outcome under the study's objectives and
    constraints. The caller reserved the numbers in this transaction (the study's row
    is locked)."""
    now = utcnow()
    values = [
        _new_trial(
            study_id=study_id,
            number=first_number + offset,
            vector=vector,
            params=param,
            now=now,
            state=add.state,
            value=outcome.value if outcome else add.value,
            values=outcome.values if outcome else None,
            feasible=outcome.feasible if outcome else None,
            message=add.message,
            metrics=dict(add.metrics),
            info={"source": "enqueued" if add.state == TrialState.queued else "added"},
            finished_at=None if add.state == TrialState.queued else now,
        )
        for offset, (vector, param, add, outcome) in enumerate(
            zip(vectors, params, adds, outcomes, strict=True)
        )
    ]
    ids = [row["id"] for row in INSERT_TRIALS.rows(session, values)]
    for trial_id, add, outcome in zip(ids, adds, outcomes, strict=True):
        value = counted_value(outcome) if outcome else add.value
        if add.state == TrialState.complete and value is not None:
            BEST.rows(session, [{"sid": study_id, "tid": trial_id, "value": value, "now": now}])
    if any(add.state not in (None, TrialState.queued) for add in adds):
        finish_if_done(session, study_id=study_id)  # the numbers' reservation locked the row
    return [
        Trial.model_validate({"id": trial_id, **row})
        for trial_id, row in zip(ids, values, strict=True)
    ]


def trials_of_vectors(
    session: Session, *, study_id: int, vectors: Sequence[Sequence[float]]
) -> dict[tuple[float, ...], Trial]:
    """The study's trials (failed ones aside) whose vector is one of ``vectors``, by
    vector (the first by number where several share one)."""
    wanted = {tuple(vector) for vector in vectors}
    rows = session.scalars(
        sa.select(TrialRow)
        .where(TrialRow.study_id == study_id, TrialRow.state != TrialState.failed)
        .order_by(TrialRow.number.desc())
    )
    return {
        tuple(row.vector): Trial.model_validate(row, from_attributes=True)
        for row in rows
        if tuple(row.vector) in wanted
    }


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
    if for_update and locking(session):
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
    numbers: Sequence[int] | None = None,
    after: int = 0,
    offset: int = 0,
    limit: int | None = None,
    order_by: str = "number",
    descending: bool = False,
) -> tuple[list[TrialRow], int]:
    """A page of a study's trials (those numbered ``after`` or more, of ``numbers`` when
    given) and the total that match."""
    get_study(session, study_id=study_id)
    where = [TrialRow.study_id == study_id]
    if state is not None:
        where.append(TrialRow.state == state.value)
    if numbers is not None:
        where.append(TrialRow.number.in_(sorted(set(numbers))))
    if after:
        where.append(TrialRow.number >= after)
    total = session.scalar(sa.select(sa.func.count()).select_from(TrialRow).where(*where)) or 0
    column = _trial_order(session, order_by)
    ordering = column.desc().nulls_last() if descending else column.asc().nulls_last()
    query = sa.select(TrialRow).where(*where).order_by(ordering, TrialRow.number)
    query = query.offset(offset)
    if limit is not None:
        query = query.limit(limit)
    return list(session.scalars(query)), total


def best_trial(session: Session, *, study_id: int) -> TrialRow:
    study = get_study(session, study_id=study_id)
    outcomes = stored_outcomes(study.outcomes, direction=study.direction)
    if outcomes.multi:
        raise ConflictError(
            f"study {study_id} has {outcomes.count} objectives ({', '.join(outcomes.names)}), "
            f"so no single best trial: its best trials are GET /api/v1/studies/{study_id}/pareto"
        )
    if study.best_trial_id is None:
        feasible = " feasible" if outcomes.constraints else ""
        raise NotFoundError(f"study {study_id} has no{feasible} complete trial yet")
    return get_trial(session, trial_id=study.best_trial_id)


def pareto_trials(session: Session, *, study_id: int) -> list[TrialRow]:
    """The study's complete, feasible trials that no other one dominates, by number (for
    one objective: those with the best value)."""
    study = get_study(session, study_id=study_id)
    outcomes = stored_outcomes(study.outcomes, direction=study.direction)
    rows = list(
        session.scalars(
            sa.select(TrialRow)
            .where(
                TrialRow.study_id == study_id,
                TrialRow.state == TrialState.complete,
                sa.or_(TrialRow.feasible.is_(None), TrialRow.feasible.is_(True)),
            )
            .order_by(TrialRow.number)
        )
    )
    told: list[tuple[TrialRow, list[float]]] = []
    for row in rows:
        point = row.values if outcomes.multi else [row.value]
        if point is not None and len(point) == outcomes.count and None not in point:
            told.append((row, cast(list[float], point)))
    front = pareto_front([point for _, point in told], outcomes.signs)
    return [told[index][0] for index in front]
