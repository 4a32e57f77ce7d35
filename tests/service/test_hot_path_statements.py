"""What the hot path sends to the database: every statement of an ask, counted on
SQLite's driver (its trace callback sees the driver's statements and SQLAlchemy's
alike). Each statement is a round trip on PostgreSQL, and each one that writes the
study row holds that row's lock until the commit."""

from __future__ import annotations

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
from adservice.repository import studies as study_repo
from adservice.services.configs import StudyConfigs
from adservice.services.trials import propose_trials

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
