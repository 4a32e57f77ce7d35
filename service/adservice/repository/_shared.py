"""What several modules of :mod:`adservice.repository` share: whether the database locks
rows, which version of its study's shared controller a trial made, a worker's last-seen
upkeep, the value a finished trial offers as a study's best, and the hot-path statements
ask and tell run on every request (built once).

Private to the package: it imports no module of it.
"""

from __future__ import annotations

import enum
from collections.abc import Sequence
from datetime import datetime
from typing import Any, cast

import sqlalchemy as sa
from sqlalchemy.orm import Session

from adclient.objectives import Outcome
from adclient.schemas import TrialState
from adservice.db import Prepared
from adservice.models import StudyRow, TrialRow, WorkerRow


def locking(session: Session) -> bool:
    """Row locks (``FOR UPDATE SKIP LOCKED``) where the database has them."""
    return session.get_bind().dialect.name == "postgresql"


class Unset(enum.Enum):
    """A keyword not given (where None means something)."""

    UNSET = enum.auto()


UNSET = Unset.UNSET


def made_version(info: dict[str, Any] | None) -> int | None:
    """The version of its study's shared controller a trial made (its
    ``info.shared.version``), or None."""
    shared = (info or {}).get("shared")
    version = shared.get("version") if isinstance(shared, dict) else None
    return version if isinstance(version, int) else None


def touch_worker(
    session: Session,
    *,
    worker_id: str,
    now: datetime,
    current_trial_id: int | None,
    tasks: Sequence[str] | Unset | None = UNSET,
    learners: Sequence[str] | Unset | None = UNSET,
) -> None:
    """Record that ``worker_id`` was seen at ``now``, holding ``current_trial_id`` (a
    worker seen for the first time gets its row); at a lease, the ``tasks`` and
    ``learners`` it serves (None: any). One UPDATE where the worker has its row (after
    the session's pending changes: this runs on the scope's connection)."""
    session.flush()
    params: dict[str, Any] = {"wid": worker_id, "now": now, "tid": current_trial_id}
    served = not isinstance(tasks, Unset) and not isinstance(learners, Unset)
    if served:
        params["tasks"] = None if tasks is None else sorted(cast(Sequence[str], tasks))
        params["learners"] = None if learners is None else sorted(cast(Sequence[str], learners))
    if TOUCH_WORKER[served].row(session, params) is None:
        INSERT_WORKER.rows(
            session,
            [{"tasks": None, "learners": None} | params | {"jobs_done": 0, "jobs_failed": 0}],
        )


def served_changed(
    session: Session,
    *,
    worker_id: str,
    tasks: Sequence[str] | None,
    learners: Sequence[str] | None,
) -> bool:
    """Whether ``worker_id`` is new, or serves other ``tasks`` or ``learners`` than its
    row says (one indexed read)."""
    row = session.execute(
        sa.select(_workers.c.tasks, _workers.c.learners).where(_workers.c.worker_id == worker_id)
    ).one_or_none()
    return row is None or (row.tasks, row.learners) != (
        None if tasks is None else sorted(tasks),
        None if learners is None else sorted(learners),
    )


def counted_value(outcome: Outcome) -> float | None:
    """The value a finished trial offers as the study's best: none for several
    objectives, or for a trial that breaks a constraint."""
    return outcome.value if outcome.feasible is not False else None


_studies = cast(sa.Table, StudyRow.__table__)
_trials = cast(sa.Table, TrialRow.__table__)
_workers = cast(sa.Table, WorkerRow.__table__)


# Hot-path statements, built once: ask and tell run these on every request.
def _reserve_statement(*, proposing: bool) -> sa.Update:
    """Reserve trial numbers of a running study with room. ``proposing``: a proposal's
    reservation, which also clears the study's recorded proposal failures (the proposal
    that follows in the same transaction succeeded, or the transaction rolls back) and
    returns the fallback reason the study holds (cleared only where one is held)."""
    values: dict[Any, Any] = {
        _studies.c.n_trials: _studies.c.n_trials + sa.bindparam("count"),
        _studies.c.updated_at: sa.bindparam("now"),
    }
    returned = [_studies.c.n_trials]
    if proposing:
        values |= {
            _studies.c.proposal_failures: 0,
            _studies.c.proposal_error: None,
            _studies.c.proposal_retry_at: None,
        }
        returned.append(_studies.c.proposal_fallback_reason)
    return (
        sa.update(_studies)
        .where(
            _studies.c.id == sa.bindparam("sid"),
            _studies.c.state == "running",
            sa.or_(
                _studies.c.max_trials.is_(None),
                _studies.c.n_trials + sa.bindparam("count") <= _studies.c.max_trials,
            ),
        )
        .values(values)
        .returning(*returned)
    )


RESERVE = Prepared(_reserve_statement(proposing=False))
RESERVE_PROPOSING = Prepared(_reserve_statement(proposing=True))
ADD_FALLBACKS = Prepared(
    sa.update(_studies)
    .where(_studies.c.id == sa.bindparam("sid"))
    .values(
        proposal_fallbacks=_studies.c.proposal_fallbacks + sa.bindparam("count"),
        proposal_fallback_reason=sa.bindparam("reason"),
    )
)
CLEAR_FALLBACK_REASON = Prepared(
    sa.update(_studies)
    .where(_studies.c.id == sa.bindparam("sid"))
    .values(proposal_fallback_reason=None)
)


INSERT_TRIALS = Prepared(sa.insert(_trials).returning(_trials.c.id, sort_by_parameter_order=True))


_queued = _trials.alias("queued")
CLAIM_QUEUED = Prepared(
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


_STUDY_FULL = (
    sa.select(sa.and_(_studies.c.state == "running", _studies.c.n_trials >= _studies.c.max_trials))
    .where(_studies.c.id == _trials.c.study_id)
    .scalar_subquery()
    .label("study_full")
)
"""Whether the trial's study is running with every trial numbered (``max_trials``
reached): only then can a tell finish it. A read, no lock."""


def _finish_statement(*, by_worker: bool, checked: bool) -> sa.Update:
    """Finish a trial the caller may finish: a worker the trial it holds (with auth on,
    leased by its own token); otherwise a trial no worker holds (with auth on, of a study
    the caller owns); ``checked=False`` for admins and with auth off. Returns the trial's
    row and ``study_full``."""
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
        .returning(*_trials.c, _STUDY_FULL)
    )


def _best_statement() -> sa.Update:
    """A complete trial's value as the study's best where it beats the best stored (or
    none is): the only write of the study row a tell makes, and a conditional one, so
    on PostgreSQL a tell that is not a new best takes no lock on the study row."""
    value = sa.bindparam("value", type_=sa.Double)
    better = sa.or_(
        _studies.c.best_value.is_(None),
        sa.case(
            (_studies.c.direction == "maximize", _studies.c.best_value < value),
            else_=_studies.c.best_value > value,
        ),
    )
    return (
        sa.update(_studies)
        .where(_studies.c.id == sa.bindparam("sid"), better)
        .values(best_value=value, best_trial_id=sa.bindparam("tid"), updated_at=sa.bindparam("now"))
    )


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


FINISH = {
    (by_worker, checked): Prepared(_finish_statement(by_worker=by_worker, checked=checked))
    for by_worker in (False, True)
    for checked in (False, True)
}
BEST = Prepared(_best_statement())
WORKER_COUNT = {
    complete: Prepared(_worker_statement(complete=complete)) for complete in (False, True)
}
SET_OUTCOME = Prepared(
    sa.update(_trials)
    .where(_trials.c.id == sa.bindparam("tid"))
    .values(
        value=sa.bindparam("value"),
        values=sa.bindparam("values", type_=sa.JSON(none_as_null=True)),
        feasible=sa.bindparam("feasible"),
    )
    .returning(*_trials.c)
)


def _touch_statement(*, served: bool) -> sa.Update:
    values: dict[Any, Any] = {
        _workers.c.last_seen_at: sa.bindparam("now"),
        _workers.c.current_trial_id: sa.bindparam("tid"),
    }
    if served:
        values[_workers.c.tasks] = sa.bindparam("tasks", type_=_workers.c.tasks.type)
        values[_workers.c.learners] = sa.bindparam("learners", type_=_workers.c.learners.type)
    return (
        sa.update(_workers)
        .where(_workers.c.worker_id == sa.bindparam("wid"))
        .values(values)
        .returning(_workers.c.worker_id)
    )


TOUCH_WORKER = {served: Prepared(_touch_statement(served=served)) for served in (False, True)}
INSERT_WORKER = Prepared(
    sa.insert(_workers).values(
        worker_id=sa.bindparam("wid"),
        last_seen_at=sa.bindparam("now"),
        current_trial_id=sa.bindparam("tid"),
        jobs_done=sa.bindparam("jobs_done"),
        jobs_failed=sa.bindparam("jobs_failed"),
        tasks=sa.bindparam("tasks", type_=_workers.c.tasks.type),
        learners=sa.bindparam("learners", type_=_workers.c.learners.type),
    )
)
