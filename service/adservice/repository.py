"""Repository: every read and write of studies, trials, workers and artifacts.

Functions take an open session (from ``Database.read``/``Database.write``, the one
place that commits) and keyword-only arguments; they raise domain errors and
return ORM rows, which ``adservice.convert`` turns into API schemas.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from datetime import datetime, timedelta
from typing import Any, cast

import numpy as np
import sqlalchemy as sa
from sqlalchemy.orm import Session

from adclient.objectives import (
    Outcome,
    OutcomeError,
    Outcomes,
    outcomes_json,
    pareto_front,
    stored_outcomes,
)
from adclient.schemas import StudyCreate, TellRequest, Trial, TrialAdd, TrialState
from adservice import principals
from adservice.db import Prepared
from adservice.errors import (
    ConflictError,
    ForbiddenError,
    InvalidError,
    LeaseLostError,
    NotFoundError,
    TooLargeError,
)
from adservice.models import (
    ArtifactRow,
    SessionRow,
    StudyRow,
    TokenRow,
    TrialReportRow,
    TrialRow,
    WorkerRow,
    utcnow,
)
from adservice.principals import Principal
from adservice.repository_transfer import record_transfer_from

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


def _locking(session: Session) -> bool:
    """Row locks (``FOR UPDATE SKIP LOCKED``) where the database has them."""
    return session.get_bind().dialect.name == "postgresql"


# --- studies -------------------------------------------------------------------------


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


def stop_study(session: Session, *, study_id: int, caller: Principal) -> StudyRow:
    """Stop proposing and leasing; queued trials are dropped as failed."""
    study = get_study(session, study_id=study_id, for_update=True)
    check_manager(study, caller)
    if study.state != "running":
        return study
    now = utcnow()
    dropped = cast(
        sa.CursorResult[Any],
        session.execute(
            sa.update(TrialRow)
            .where(TrialRow.study_id == study_id, TrialRow.state == TrialState.queued)
            .values(state=TrialState.failed, message="study stopped", finished_at=now)
        ),
    ).rowcount
    study.n_failed += dropped or 0
    study.state = "stopped"
    study.updated_at = now
    return study


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


def study_history(
    session: Session,
    *,
    study_id: int,
    dim: int,
    pruned_as_observed: bool = True,
    outcomes: Outcomes | None = None,
) -> History:
    """``pruned_as_observed``: a pruned trial with a value (its last report) counts as an
    observation of that value; otherwise it is left out (docs/pruning.md). A study of
    several objectives observes its complete trials only (a pruned one has no values);
    an infeasible trial is observed, with its slacks."""
    outcomes = outcomes or Outcomes()
    columns: list[Any] = [TrialRow.state, TrialRow.vector, TrialRow.value]
    if not outcomes.plain:
        columns += [TrialRow.values, TrialRow.metrics]
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
    return History(
        X=stack([row.vector for row, _ in seen]),
        y=values[:, 0].copy(),
        failed=stack([row.vector for row in rows if row.state == TrialState.failed]),
        pending=stack(
            [row.vector for row in rows if row.state in (TrialState.queued, TrialState.running)]
        ),
        values=values if outcomes.multi else None,
        slacks=slacks,
    )


def _slacks(outcomes: Outcomes, row: Any, values: list[float]) -> list[float]:
    """A trial's constraint slacks; a pruned trial (no metrics told) counts as breaking
    none, as its value alone is what the proposer learns from it."""
    try:
        return outcomes.slacks(row.metrics or {}, values)
    except OutcomeError:
        return [0.0] * len(outcomes.constraints)


# --- trials ---------------------------------------------------------------------------


_studies = cast(sa.Table, StudyRow.__table__)
_trials = cast(sa.Table, TrialRow.__table__)
_workers = cast(sa.Table, WorkerRow.__table__)

# Hot-path statements, built once: ask and tell run these on every request.
_RESERVE = Prepared(
    sa.update(_studies)
    .where(
        _studies.c.id == sa.bindparam("sid"),
        _studies.c.state == "running",
        sa.or_(
            _studies.c.max_trials.is_(None),
            _studies.c.n_trials + sa.bindparam("count") <= _studies.c.max_trials,
        ),
    )
    .values(n_trials=_studies.c.n_trials + sa.bindparam("count"), updated_at=sa.bindparam("now"))
    .returning(_studies.c.n_trials)
)


def reserve_numbers(session: Session, *, study_id: int, count: int) -> int:
    """Claim the next ``count`` trial numbers of a running study with room; returns the
    first. One conditional UPDATE: it checks, reserves and (on PostgreSQL) row-locks."""
    reserved = _RESERVE.row(session, {"sid": study_id, "count": count, "now": utcnow()})
    if reserved is None:
        check_room(get_study(session, study_id=study_id), count=count)
        raise ConflictError(f"study {study_id} takes no new trials")  # changed meanwhile
    return int(reserved["n_trials"]) - count


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
        "created_at": now,
        "started_at": None,
        "finished_at": None,
        "heartbeat_at": None,
        "lease_expires_at": None,
        "lease_token_id": None,
    } | columns


_INSERT_TRIALS = Prepared(sa.insert(_trials).returning(_trials.c.id, sort_by_parameter_order=True))


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
) -> list[Trial]:
    """New trials numbered from ``first_number`` (see :func:`reserve_numbers`), in state
    ``running`` and leased to ``worker_id`` (and its token) when given. A ``Prepared``
    statement in the session's transaction: no ORM bookkeeping per trial."""
    now = utcnow()
    lease: dict[str, Any] = {}
    if worker_id:
        lease = {
            "worker_id": worker_id,
            "attempts": 1,
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
    ids = [row["id"] for row in _INSERT_TRIALS.rows(session, values)]
    if worker_id:
        _touch_worker(session, worker_id=worker_id, now=now, current_trial_id=ids[0])
    return [
        Trial.model_validate({"id": trial_id, **row})
        for trial_id, row in zip(ids, values, strict=True)
    ]


_queued = _trials.alias("queued")
_CLAIM_QUEUED = Prepared(
    sa.update(_trials)
    .where(
        _trials.c.id.in_(
            sa.select(_queued.c.id)
            .where(_queued.c.study_id == sa.bindparam("sid"), _queued.c.state == "queued")
            .order_by(_queued.c.id)  # the (study_id, state) index's own order: no scan
            .limit(sa.bindparam("count"))
            .with_for_update(skip_locked=True)
        )
    )
    .values(state=TrialState.running.value, started_at=sa.bindparam("now"))
    .returning(*_trials.c)
)


def claim_queued(session: Session, *, study_id: int, count: int) -> list[Trial]:
    """Up to ``count`` of the study's queued trials, oldest first, now running: an ask
    hands out enqueued trials before proposing (one indexed lookup when none wait; on
    PostgreSQL concurrent asks skip each other's rows)."""
    rows = _CLAIM_QUEUED.rows(session, [{"sid": study_id, "count": count, "now": utcnow()}])
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
    ask or a lease; finished ones count in the study's counters and best, as a tell of
    them would (``info.source`` says which: ``enqueued`` or ``added``). ``outcomes``: a
    complete one's outcome under the study's objectives and constraints."""
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
    ids = [row["id"] for row in _INSERT_TRIALS.rows(session, values)]
    for trial_id, add, outcome in zip(ids, adds, outcomes, strict=True):
        if add.state is not None and add.state != TrialState.queued:
            value = counted_value(outcome) if outcome else add.value
            _COUNT[add.state].rows(
                session, [{"sid": study_id, "tid": trial_id, "value": value, "now": now}]
            )
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
    after: int = 0,
    offset: int = 0,
    limit: int | None = None,
    order_by: str = "number",
    descending: bool = False,
) -> tuple[list[TrialRow], int]:
    """A page of a study's trials (those numbered ``after`` or more) and the total that
    match."""
    get_study(session, study_id=study_id)
    where = [TrialRow.study_id == study_id]
    if state is not None:
        where.append(TrialRow.state == state.value)
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


def _finish_statement(*, by_worker: bool, checked: bool) -> sa.Update:
    """Finish a trial the caller may finish: a worker the trial it holds (with auth on,
    leased by its own token); otherwise a trial no worker holds (with auth on, of a study
    the caller owns); ``checked=False`` for admins and with auth off."""
    holder: list[sa.ColumnElement[bool]]
    if by_worker:
        holder = [
            _trials.c.state == TrialState.running.value,
            _trials.c.worker_id == sa.bindparam("wid"),
        ]
        if checked:
            holder.append(_trials.c.lease_token_id == sa.bindparam("tok"))
    else:
        holder = [  # not IN: a prepared statement takes no expanding parameters
            sa.or_(
                _trials.c.state == TrialState.queued.value,
                _trials.c.state == TrialState.running.value,
            )
        ]
        if checked:
            owned = sa.select(_studies.c.id).where(_studies.c.owner_token_id == sa.bindparam("tok"))
            holder += [_trials.c.worker_id.is_(None), _trials.c.study_id.in_(owned)]
    return (
        sa.update(_trials)
        .where(_trials.c.id == sa.bindparam("tid"), *holder)
        .values(
            state=sa.bindparam("state"),
            value=sa.bindparam("value"),
            message=sa.bindparam("message"),
            metrics=sa.bindparam("metrics", type_=sa.JSON),
            finished_at=sa.bindparam("now"),
            lease_expires_at=None,
            started_at=sa.func.coalesce(_trials.c.started_at, sa.bindparam("now")),
        )
        .returning(*_trials.c)
    )


def _count_statement(*, state: str) -> sa.Update:
    complete = state == TrialState.complete
    counter = {
        TrialState.complete: _studies.c.n_complete,
        TrialState.failed: _studies.c.n_failed,
        TrialState.pruned: _studies.c.n_pruned,
    }[TrialState(state)]
    updates: dict[Any, Any] = {counter: counter + 1, _studies.c.updated_at: sa.bindparam("now")}
    if complete:
        value = sa.bindparam("value", type_=sa.Double)
        # No value (several objectives, or a trial breaking a constraint): not a best.
        better = sa.and_(
            sa.cast(value, sa.Double).is_not(None),  # typed: PostgreSQL infers none here
            sa.or_(
                _studies.c.best_value.is_(None),
                sa.case(
                    (_studies.c.direction == "maximize", _studies.c.best_value < value),
                    else_=_studies.c.best_value > value,
                ),
            ),
        )
        updates[_studies.c.best_value] = sa.case((better, value), else_=_studies.c.best_value)
        updates[_studies.c.best_trial_id] = sa.case(
            (better, sa.bindparam("tid")), else_=_studies.c.best_trial_id
        )
    finished = _studies.c.n_complete + _studies.c.n_failed + _studies.c.n_pruned
    done = finished + 1 >= _studies.c.max_trials
    updates[_studies.c.state] = sa.case(
        (sa.and_(_studies.c.state == "running", done), "complete"), else_=_studies.c.state
    )
    return sa.update(_studies).where(_studies.c.id == sa.bindparam("sid")).values(updates)


def _worker_statement(*, complete: bool) -> sa.Update:
    counter = _workers.c.jobs_done if complete else _workers.c.jobs_failed
    return (
        sa.update(_workers)
        .where(_workers.c.worker_id == sa.bindparam("wid"))
        .values(
            {
                counter: counter + 1,
                _workers.c.last_seen_at: sa.bindparam("now"),
                _workers.c.current_trial_id: sa.case(
                    (_workers.c.current_trial_id == sa.bindparam("tid"), None),
                    else_=_workers.c.current_trial_id,
                ),
            }
        )
    )


_FINISH = {
    (by_worker, checked): Prepared(_finish_statement(by_worker=by_worker, checked=checked))
    for by_worker in (False, True)
    for checked in (False, True)
}
_COUNT = {
    state: Prepared(_count_statement(state=state)) for state in ("complete", "failed", "pruned")
}
_WORKER_COUNT = {
    complete: Prepared(_worker_statement(complete=complete)) for complete in (False, True)
}
_SET_OUTCOME = Prepared(
    sa.update(_trials)
    .where(_trials.c.id == sa.bindparam("tid"))
    .values(
        value=sa.bindparam("value"),
        values=sa.bindparam("values", type_=sa.JSON(none_as_null=True)),
        feasible=sa.bindparam("feasible"),
    )
    .returning(*_trials.c)
)

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


def counted_value(outcome: Outcome) -> float | None:
    """The value a finished trial offers as the study's best: none for several
    objectives, or for a trial that breaks a constraint."""
    return outcome.value if outcome.feasible is not False else None


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

    The common case is two conditional UPDATEs (trial, then study counters and best);
    only a tell that changes nothing takes the slow path that finds out why, and only a
    study of several objectives or with constraints (``cached_outcomes``, else read from
    the study row) a third that stores the outcome. The UPDATEs are ``Prepared``
    statements, run in the session's transaction."""
    now = utcnow()
    complete = body.state != "failed"  # a pruned trial did its job: the worker's jobs_done
    value = body.value
    if body.state == "pruned" and value is None:
        value = _last_reported_value(session, trial_id=trial_id)
    finished = _FINISH[body.worker_id is not None, caller.checked].row(
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
    if body.transfer_from is not None:
        record_transfer_from(session, trial_id=trial_id, source_id=body.transfer_from)
        finished = {**finished, "info": {**finished["info"], "transfer_from": body.transfer_from}}
    if body.state == "complete":
        outcomes = _outcomes(session, finished["study_id"], cached_outcomes)
        if not outcomes.plain or body.values is not None:
            try:
                outcome = outcomes.outcome(
                    value=body.value, values=body.values, metrics=body.metrics
                )
            except OutcomeError as error:
                raise InvalidError(str(error)) from None
            finished = _SET_OUTCOME.row(
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
    _COUNT[body.state].rows(
        session, [{"sid": finished["study_id"], "tid": trial_id, "value": value, "now": now}]
    )
    if finished["worker_id"] is not None:
        _WORKER_COUNT[complete].rows(
            session, [{"wid": finished["worker_id"], "tid": trial_id, "now": now}]
        )
    return Trial.model_validate(finished)


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


def _finish_study_if_done(study: StudyRow) -> None:
    if (
        study.state == "running"
        and study.max_trials is not None
        and study.n_complete + study.n_failed + study.n_pruned >= study.max_trials
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
    if expired and _locking(session):
        # The counters below are read-modify-write: lock the studies (in id order, after
        # the trials, as a tell does) and reload them, or a concurrent tell's count is lost.
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
            study.n_failed += 1
            if worker is not None:
                worker.jobs_failed = WorkerRow.jobs_failed + 1  # in SQL: the row is not locked
            _finish_study_if_done(study)
        else:
            trial.state = TrialState.queued
            trial.worker_id = None
            trial.lease_token_id = None
        study.updated_at = now
    return len(expired)


def _task_among(tasks: Sequence[str] | None) -> list[sa.ColumnElement[bool]]:
    """Managed studies, and with ``tasks`` only those whose task has one of these names."""
    where: list[sa.ColumnElement[bool]] = [StudyRow.task.is_not(None)]
    if tasks is not None:
        where.append(StudyRow.task["name"].as_string().in_(list(tasks)))
    return where


def lease_queued_trial(
    session: Session,
    *,
    worker_id: str,
    lease_token_id: int | None,
    lease_seconds: float,
    tasks: Sequence[str] | None = None,
) -> TrialRow | None:
    """Lease the oldest queued trial of a running managed study (of one of ``tasks``)."""
    now = utcnow()
    expire_leases(session, now=now)
    query = (
        sa.select(TrialRow)
        .join(StudyRow, StudyRow.id == TrialRow.study_id)
        .where(
            TrialRow.state == TrialState.queued,
            StudyRow.state == "running",
            *_task_among(tasks),
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
    trial.lease_token_id = lease_token_id
    trial.attempts += 1
    trial.started_at = now
    trial.heartbeat_at = now
    trial.lease_expires_at = now + timedelta(seconds=lease_seconds)
    _touch_worker(session, worker_id=worker_id, now=now, current_trial_id=trial.id)
    return trial


def studies_wanting_trials(session: Session, *, tasks: Sequence[str] | None = None) -> list[int]:
    """Running managed studies (of one of ``tasks``) with room for a trial, oldest first."""
    query = (
        sa.select(StudyRow.id)
        .where(
            StudyRow.state == "running",
            *_task_among(tasks),
            StudyRow.n_trials < StudyRow.max_trials,
        )
        .order_by(StudyRow.id)
    )
    return list(session.scalars(query))


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


def check_manager(study: StudyRow, caller: Principal) -> None:
    """Asking, telling, stopping or deleting a study is for its owner (or an admin)."""
    principals.check_manager(
        caller, study_id=study.id, owner_token_id=study.owner_token_id, owner_name=study.created_by
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
    _touch_worker(session, worker_id=worker_id, now=now, current_trial_id=trial.id)
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
        _touch_worker(session, worker_id=holder, now=utcnow(), current_trial_id=None)
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


@dataclass(frozen=True)
class ArtifactQuota:
    count: int
    """Artifacts one trial may have."""
    total_bytes: int
    """Bytes all of one trial's artifacts may take."""


def artifact_room(
    session: Session,
    *,
    trial_id: int,
    name: str,
    worker_id: str | None,
    caller: Principal,
    quota: ArtifactQuota,
) -> tuple[TrialRow, int]:
    """The trial an upload may write to, and how many bytes it may write: only while the
    trial runs, by its lease holder (or, for an asked trial, the study's owner), within
    the trial's quota (``name``'s present file, which it would replace, not counted)."""
    trial = get_trial(session, trial_id=trial_id, for_update=True)
    if trial.state != TrialState.running:
        raise ConflictError(
            f"trial {trial_id} is {trial.state}: artifacts are uploaded while it runs"
        )
    if trial.worker_id is None:
        check_manager(get_study(session, study_id=trial.study_id), caller)
    else:
        held_trial(session, trial_id=trial_id, worker_id=worker_id, caller=caller)
    others = session.execute(
        sa.select(sa.func.count(), sa.func.coalesce(sa.func.sum(ArtifactRow.size), 0)).where(
            ArtifactRow.trial_id == trial_id, ArtifactRow.name != name
        )
    ).one()
    if others[0] >= quota.count:
        raise TooLargeError(f"trial {trial_id} already has {others[0]} artifacts, the most allowed")
    room = quota.total_bytes - int(others[1])
    if room <= 0:
        raise TooLargeError(
            f"trial {trial_id}'s artifacts already take {others[1]} bytes of its "
            f"{quota.total_bytes}"
        )
    return trial, room


def record_artifact(
    session: Session,
    *,
    trial_id: int,
    name: str,
    content_type: str,
    size: int,
    sha256: str,
    path: str,
    worker_id: str | None,
    caller: Principal,
    quota: ArtifactQuota,
) -> tuple[ArtifactRow, str | None]:
    """Record an artifact whose file is already complete on disk (last step of a PUT),
    checking again that the lease and the quota still allow it; also returns the path of
    the file it replaces, if any (the caller removes it after the commit)."""
    _, room = artifact_room(
        session, trial_id=trial_id, name=name, worker_id=worker_id, caller=caller, quota=quota
    )
    if size > room:
        raise TooLargeError(f"trial {trial_id}'s artifacts would exceed {quota.total_bytes} bytes")
    row = session.scalars(
        sa.select(ArtifactRow).where(ArtifactRow.trial_id == trial_id, ArtifactRow.name == name)
    ).one_or_none()
    replaced = row.path if row is not None and row.path != path else None
    if row is None:
        row = ArtifactRow(trial_id=trial_id, name=name)
        session.add(row)
    row.content_type = content_type
    row.size = size
    row.sha256 = sha256
    row.path = path
    row.created_at = utcnow()
    session.flush()
    return row, replaced


def artifact_path(session: Session, *, trial_id: int, name: str) -> str | None:
    """Where the stored artifact ``name`` of a trial lives, if there is one."""
    return session.scalar(
        sa.select(ArtifactRow.path).where(
            ArtifactRow.trial_id == trial_id, ArtifactRow.name == name
        )
    )


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


# --- tokens ---------------------------------------------------------------------------


def create_token(session: Session, *, name: str, role: str, digest: str) -> TokenRow:
    row = TokenRow(name=name, role=role, token_sha256=digest)
    session.add(row)
    session.flush()
    return row


def find_token(session: Session, *, digest: str) -> TokenRow | None:
    return session.scalars(
        sa.select(TokenRow).where(TokenRow.token_sha256 == digest, TokenRow.revoked_at.is_(None))
    ).one_or_none()


def list_tokens(session: Session) -> list[TokenRow]:
    return list(session.scalars(sa.select(TokenRow).order_by(TokenRow.id)))


def revoke_token(session: Session, *, token_id: int) -> TokenRow:
    row = session.get(TokenRow, token_id)
    if row is None:
        raise NotFoundError(f"token {token_id} not found")
    if row.revoked_at is None:
        row.revoked_at = utcnow()
    return row


# --- dashboard sessions -----------------------------------------------------------------


def create_session(
    session: Session, *, digest: str, token_id: int, csrf_token: str, expires_at: datetime
) -> SessionRow:
    row = SessionRow(
        id_sha256=digest, token_id=token_id, csrf_token=csrf_token, expires_at=expires_at
    )
    session.add(row)
    session.flush()
    return row


def find_session(session: Session, *, digest: str) -> tuple[SessionRow, TokenRow] | None:
    """A live sign-in and its token (none once expired or once the token is revoked)."""
    found = session.execute(
        sa.select(SessionRow, TokenRow)
        .join(TokenRow, TokenRow.id == SessionRow.token_id)
        .where(
            SessionRow.id_sha256 == digest,
            SessionRow.expires_at > utcnow(),
            TokenRow.revoked_at.is_(None),
        )
    ).one_or_none()
    return None if found is None else (found[0], found[1])


def delete_session(session: Session, *, digest: str) -> None:
    """Sign out; expired sign-ins go with it."""
    session.execute(
        sa.delete(SessionRow).where(
            sa.or_(SessionRow.id_sha256 == digest, SessionRow.expires_at <= utcnow())
        )
    )
