"""What the hot path sends to the database: every statement of an ask and a lease,
counted on SQLite's driver (its trace callback sees the driver's statements and SQLAlchemy's
alike). Each statement is a round trip on PostgreSQL, and each one that writes the
study row holds that row's lock until the commit."""

from __future__ import annotations

import asyncio
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import sqlalchemy as sa

from adclient.schemas import StudyCreate
from adservice.auth import Role
from adservice.db import Database, upgrade_to_head
from adservice.locks import StudyLocks
from adservice.principals import Principal
from adservice.proposal_runner import ProposalRunner
from adservice.repository import leases as lease_repo
from adservice.repository import studies as study_repo
from adservice.services.configs import StudyConfigs
from adservice.services.jobs import lease_job
from adservice.services.trials import Proposing, propose_trials

ADMIN = Principal(role=Role.admin, token_id=None)
BOX = {"type": "box", "params": [{"name": "x", "low": 0, "high": 1}]}


@pytest.fixture
def traced(tmp_path: Path) -> Iterator[tuple[Database, list[str]]]:
    """A migrated SQLite database whose connections report every statement they run."""
    url = f"sqlite:///{tmp_path / 'traced.db'}"
    upgrade_to_head(url)
    db = Database(url)
    statements: list[str] = []

    @sa.event.listens_for(db.engine, "connect")
    def _trace(dbapi_connection: Any, _record: Any) -> None:
        dbapi_connection.set_trace_callback(statements.append)

    yield db, statements
    db.dispose()


def _study(db: Database, **fields: Any) -> int:
    body = StudyCreate.model_validate(
        {"name": "traced", "space": BOX, "proposer": {"name": "random"}, **fields}
    )
    with db.write() as session:
        return study_repo.create_study(session, body=body, representation=None, owner=ADMIN).id


def _study_writes(statements: list[str]) -> list[str]:
    return [s for s in statements if s.lstrip().upper().startswith("UPDATE STUDIES")]


def test_an_ask_writes_the_study_row_once(traced: tuple[Database, list[str]]) -> None:
    """Reserving the numbers, clearing recorded proposal failures and (where none is
    held) the fallback reason are one UPDATE of the study, not three."""
    db, statements = traced
    study_id = _study(db)
    configs, locks = StudyConfigs(db), StudyLocks()
    propose_trials(db, configs, locks, study_id=study_id, count=1, caller=ADMIN)  # cached
    statements.clear()
    (trial,) = propose_trials(db, configs, locks, study_id=study_id, count=1, caller=ADMIN)
    assert trial.number == 1
    assert len(_study_writes(statements)) == 1, statements


def _writes(statements: list[str]) -> list[list[str]]:
    """The transactions that wrote, each as its statements (BEGIN to COMMIT)."""
    transactions: list[list[str]] = []
    current: list[str] = []
    for statement in statements:
        verb = statement.lstrip().split(None, 1)[0].upper()
        if verb == "BEGIN":
            current = []
        elif verb == "COMMIT":
            if any(s.lstrip().split(None, 1)[0].upper() in ("INSERT", "UPDATE") for s in current):
                transactions.append(current)
        else:
            current.append(statement)
    return transactions


def _workers(db: Database) -> dict[str, tuple[Any, ...]]:
    with db.read() as session:
        return {
            w.worker_id: (w.current_trial_id, w.tasks, w.learners, w.last_seen_at)
            for w in lease_repo.list_workers(session)
        }


def test_a_lease_that_proposes_commits_one_write(traced: tuple[Database, list[str]]) -> None:
    """With nothing queued, the lease's look for a queued trial writes nothing (its
    worker is known, serving the same tasks): the proposal's write, which leases the new
    trial, records the worker too. One commit that waits for the disk, not two; a lease
    that finds no work still records its worker as seen."""
    db, statements = traced
    _study(db, task={"name": "noop", "external": True}, max_trials=3)
    proposing = Proposing(db, StudyConfigs(db), StudyLocks(), ProposalRunner(1))

    def lease(worker_id: str, tasks: list[str] | None = None) -> int | None:
        job = asyncio.run(
            lease_job(
                proposing,
                worker_id=worker_id,
                caller=ADMIN,
                lease_seconds=60,
                tasks=tasks,
            )
        )
        return None if job is None else job.trial_id

    try:
        first = lease("w1")
        assert _workers(db)["w1"][:3] == (first, None, None)
        statements.clear()
        second = lease("w1")
        writes = _writes(statements)
        assert len(writes) == 1, writes
        assert _workers(db)["w1"][:3] == (second, None, None)
        third = lease("w1", tasks=["noop"])  # serves other tasks now: written at once
        seen = _workers(db)["w1"]
        assert seen[:3] == (third, ["noop"], None)
        assert lease("w1", tasks=["noop"]) is None  # the study is full: no work
        idle = _workers(db)["w1"]
        assert idle[:3] == (None, ["noop"], None) and idle[3] > seen[3]
    finally:
        proposing.runner.shutdown()
