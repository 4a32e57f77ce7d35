"""Row locking on PostgreSQL, where writers really run at once (SQLite takes turns):
two transactions are interleaved by hand and the result must be as if they took turns."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from datetime import timedelta
from typing import Any

import pytest
import sqlalchemy as sa
from sqlalchemy.orm import Session

from adclient.schemas import StudyCreate, TellRequest
from adservice.db import Database, upgrade_to_head
from adservice.locks import StudyLocks
from adservice.models import utcnow
from adservice.principals import OPEN_ADMIN
from adservice.repository import leases as lease_repo
from adservice.repository import promotion as promotion_repo
from adservice.repository import studies as study_repo
from adservice.repository import tell as tell_repo
from adservice.repository import trials as trial_repo
from adservice.services.configs import StudyConfigs
from adservice.services.trials import propose_trials

pytestmark = pytest.mark.postgres


@pytest.fixture
def db(new_postgres_url: Callable[[], str]) -> Iterator[Database]:
    url = new_postgres_url()
    upgrade_to_head(url)
    database = Database(url)
    yield database
    database.dispose()


def _study(db: Database, *, max_trials: int, workers: int) -> tuple[int, list[int]]:
    """A managed study of ``max_trials`` and, numbered and leased, one trial per worker
    ``w0``, ``w1``, ... (all of them when ``workers == max_trials``)."""
    body = StudyCreate.model_validate(
        {
            "name": "race",
            "space": {"type": "box", "params": [{"name": "x", "low": 0, "high": 1}]},
            "proposer": {"name": "random"},
            "task": {"name": "noop", "external": True},
            "max_trials": max_trials,
            "max_attempts": 1,
        }
    )
    with db.write() as session:
        study_id = study_repo.create_study(
            session, body=body, representation=None, owner=OPEN_ADMIN
        ).id
        first = trial_repo.reserve_numbers(session, study_id=study_id, count=workers)
        trials = [
            trial_repo.insert_trials(
                session,
                study_id=study_id,
                first_number=first + i,
                vectors=[[0.5]],
                params=[{"x": 0.5}],
                infos=[{}],
                worker_id=f"w{i}",
            )[0].id
            for i in range(workers)
        ]
    return study_id, trials


def _tell(session: Session, trial_id: int, worker: str, value: float | None) -> None:
    """A worker's tell (failed without a value), refused rather than left waiting where
    it would queue on a row lock for more than a few seconds."""
    session.execute(sa.text("SET LOCAL lock_timeout = '5s'"))
    body = (
        TellRequest(state="failed", message="crashed", worker_id=worker)
        if value is None
        else TellRequest(value=value, worker_id=worker)
    )
    tell_repo.tell_trial(session, trial_id=trial_id, body=body, caller=OPEN_ADMIN)


def _counts(db: Database, study_id: int) -> tuple[dict[str, int], str, float | None]:
    with db.read() as session:
        study = study_repo.get_study(session, study_id=study_id)
        counts = study_repo.state_counts(session, study_ids=[study_id])[study_id]
        return counts, study.state, study.best_value


def test_a_tell_that_is_no_new_best_does_not_wait_for_the_study_row(db: Database) -> None:
    """While another transaction holds the study's row (a lease's proposal reserving a
    number, say), tells that are not a new best, and failed ones, go through: a tell
    writes no counter of the study. (Before, every tell updated the study row's counters
    and waited here: refused by the lock timeout.)"""
    study_id, trials = _study(db, max_trials=10, workers=3)
    with db.write() as session:
        _tell(session, trials[0], "w0", 2.0)
    with db.engine.connect() as holder:
        holder.execute(
            sa.text("SELECT id FROM studies WHERE id = :id FOR UPDATE"), {"id": study_id}
        )
        with db.write() as session:
            _tell(session, trials[1], "w1", 1.0)  # a maximised study: 1.0 is no new best
        with db.write() as session:
            _tell(session, trials[2], "w2", None)
        holder.rollback()
    counts, state, best = _counts(db, study_id)
    assert (counts, state, best) == ({"complete": 2, "failed": 1}, "running", 2.0)


def test_the_last_two_tells_at_once_finish_the_study(db: Database) -> None:
    """The study's last two tells, each uncommitted while the other runs, see neither
    the other's trial: the one that commits first finds one trial still running, the
    other, checking after its own commit (as the tell route does), finds all finished
    and completes the study. A check inside each tell's transaction would leave it
    running forever."""
    study_id, trials = _study(db, max_trials=2, workers=2)
    with db.write() as first:
        _tell(first, trials[0], "w0", None)
        with db.write() as second:
            _tell(second, trials[1], "w1", 0.5)
        with db.write() as session:  # the second's check, after its commit
            study_repo.finish_if_done(session, study_id=study_id)
        assert _counts(db, study_id)[1] == "running"  # the first is not committed yet
    with db.write() as session:
        study_repo.finish_if_done(session, study_id=study_id)
    assert _counts(db, study_id) == ({"complete": 1, "failed": 1}, "complete", 0.5)


def test_a_study_whose_last_tell_did_not_check_its_end_is_finished_by_the_sweep(
    db: Database,
) -> None:
    """The server stopped between a last tell's commit and its check of the study's end:
    the study stays running with every trial ended until the lease sweep's
    ``finish_done_studies`` finishes it; a study with a trial still running is left."""
    done, done_trials = _study(db, max_trials=1, workers=1)
    busy, busy_trials = _study(db, max_trials=2, workers=2)
    with db.write() as session:
        _tell(session, done_trials[0], "w0", 0.5)
        _tell(session, busy_trials[0], "w0", 0.2)
    assert _counts(db, done)[1] == "running"
    with db.write() as session:
        assert promotion_repo.finish_done_studies(session) == 1
    assert _counts(db, done)[1] == "complete" and _counts(db, busy)[1] == "running"
    with db.write() as session:
        assert promotion_repo.finish_done_studies(session) == 0


def test_a_lease_failing_on_expiry_meanwhile_a_failed_tell_loses_no_count(db: Database) -> None:
    """Trial 0 is told failed while the sweeper fails trial 1 for its expired lease (its
    last attempt). The sweep does not wait for the tell (which locks no study row) and
    counts one finished trial; the tell's check after its commit counts both: 2 failed
    and, with max_trials 2, the study is done."""
    study_id, (told, expiring) = _study(db, max_trials=2, workers=2)
    with db.write() as session:
        trial = trial_repo.get_trial(session, trial_id=expiring)
        trial.lease_expires_at = utcnow() - timedelta(seconds=1)

    with db.write() as session:
        _tell(session, told, "w0", None)
        with db.write() as sweep:
            sweep.execute(sa.text("SET LOCAL lock_timeout = '5s'"))
            assert lease_repo.expire_leases(sweep) == 1
        assert _counts(db, study_id)[1] == "running"  # the tell is not committed yet
    with db.write() as session:  # the tell route's check after the commit
        study_repo.finish_if_done(session, study_id=study_id)

    with db.read() as session:
        states = [t.state for t in trial_repo.list_trials(session, study_id=study_id)[0]]
    assert states == ["failed", "failed"]
    assert _counts(db, study_id) == ({"failed": 2}, "complete", None)


def test_a_lease_frees_the_study_row_before_its_flush_and_records_its_worker_after(
    db: Database,
) -> None:
    """A worker's lease proposes, reserves the number (locking the study's row) and
    inserts the trial in a transaction committed without waiting for its WAL flush;
    the worker is recorded as seen, holding the trial, in the next transaction, whose
    commit waits for the flush (of both). Before, one transaction held the study's row
    through the worker's write and the flush."""
    study_id, _ = _study(db, max_trials=3, workers=0)
    statements: list[str] = []

    @sa.event.listens_for(db.engine, "before_cursor_execute")
    def _statement(*args: Any) -> None:
        statements.append(" ".join(str(args[2]).split()[:3]).upper())

    @sa.event.listens_for(db.engine, "commit")
    def _commit(*_: Any) -> None:
        statements.append("<commit>")

    configs = StudyConfigs(db)
    (trial,) = propose_trials(
        db, configs, StudyLocks(), study_id=study_id, count=1, caller=OPEN_ADMIN, worker_id="w9"
    )
    transactions = " ".join(statements).split("<commit>")
    (leased,) = [t for t in transactions if "INSERT INTO TRIALS" in t]
    assert "SET LOCAL SYNCHRONOUS_COMMIT" in leased and "UPDATE STUDIES SET" in leased
    assert "WORKERS" not in leased
    after = transactions[transactions.index(leased) + 1 :]
    assert any("UPDATE WORKERS SET" in t or "INSERT INTO WORKERS" in t for t in after)
    with db.read() as session:
        (worker,) = lease_repo.list_workers(session)
    assert (worker.worker_id, worker.current_trial_id) == ("w9", trial.id)
