"""Row locking on PostgreSQL, where writers really run at once (SQLite takes turns):
two transactions are interleaved by hand and the result must be as if they took turns."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from datetime import timedelta

import pytest
import sqlalchemy as sa

from adclient.schemas import StudyCreate, TellRequest
from adservice.db import Database, upgrade_to_head
from adservice.models import utcnow
from adservice.principals import OPEN_ADMIN
from adservice.repository import leases as lease_repo
from adservice.repository import studies as study_repo
from adservice.repository import tell as tell_repo
from adservice.repository import trials as trial_repo

pytestmark = pytest.mark.postgres


@pytest.fixture
def db(new_postgres_url: Callable[[], str]) -> Iterator[Database]:
    url = new_postgres_url()
    upgrade_to_head(url)
    database = Database(url)
    yield database
    database.dispose()


def wait_until_blocked(db: Database, count: int = 1) -> None:
    """Until ``count`` of our backends wait on a row lock (a thread reached the point)."""
    query = sa.text(
        "SELECT count(*) FROM pg_stat_activity "
        "WHERE datname = current_database() AND wait_event_type = 'Lock'"
    )
    while True:
        with db.engine.connect() as connection:
            if connection.execute(query).scalar_one() >= count:
                return
        time.sleep(0.01)


def test_a_lease_failing_on_expiry_meanwhile_a_failed_tell_loses_no_count(db: Database) -> None:
    """Trial 0 is told failed while the sweeper fails trial 1 for its expired lease (its
    last attempt). Both count: n_failed is 2 and, with max_trials 2, the study is done."""
    body = StudyCreate.model_validate(
        {
            "name": "race",
            "space": {"type": "box", "params": [{"name": "x", "low": 0, "high": 1}]},
            "proposer": {"name": "random"},
            "task": {"name": "noop", "external": True},
            "max_trials": 2,
            "max_attempts": 1,
        }
    )
    with db.write() as session:
        study_id = study_repo.create_study(
            session, body=body, representation=None, owner=OPEN_ADMIN
        ).id
        first = trial_repo.reserve_numbers(session, study_id=study_id, count=2)
        told, expiring = (
            trial_repo.insert_trials(
                session,
                study_id=study_id,
                first_number=first + i,
                vectors=[[0.5]],
                params=[{"x": 0.5}],
                infos=[{}],
                worker_id=f"w{i}",
            )[0].id
            for i in range(2)
        )
    with db.write() as session:
        trial = trial_repo.get_trial(session, trial_id=expiring)
        trial.lease_expires_at = utcnow() - timedelta(seconds=1)

    tell_stored = threading.Event()
    commit_tell = threading.Event()
    expired: list[int] = []

    def tell() -> None:
        with db.write() as session:
            request = TellRequest(state="failed", message="crashed", worker_id="w0")
            tell_repo.tell_trial(session, trial_id=told, body=request, caller=OPEN_ADMIN)
            tell_stored.set()
            commit_tell.wait()

    def sweep() -> None:
        with db.write() as session:
            expired.append(lease_repo.expire_leases(session))

    teller = threading.Thread(target=tell)
    teller.start()
    tell_stored.wait()
    sweeper = threading.Thread(target=sweep)
    sweeper.start()
    wait_until_blocked(db)  # the sweep waits for the tell's transaction
    commit_tell.set()
    teller.join()
    sweeper.join()

    assert expired == [1]
    with db.read() as session:
        study = study_repo.get_study(session, study_id=study_id)
        states = [t.state for t in trial_repo.list_trials(session, study_id=study_id)[0]]
    assert states == ["failed", "failed"]
    assert (study.n_failed, study.n_complete, study.state) == (2, 0, "complete")
