"""The hot statements run on SQLite's driver (``Prepared``) exactly as SQLAlchemy runs them:
the same script of asks, leases and tells on two SQLite files, one with the driver path
and one through SQLAlchemy, leaves the same rows and returns the same trials."""

from __future__ import annotations

from collections.abc import Iterator
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import pytest
import sqlalchemy as sa

from adclient.schemas import StudyCreate, TellRequest, Trial
from adservice.auth import Role
from adservice.db import Database, Prepared, upgrade_to_head
from adservice.errors import ConflictError, LeaseLostError
from adservice.principals import Principal
from adservice.repository import studies as study_repo
from adservice.repository import tell as tell_repo
from adservice.repository import tokens as token_repo
from adservice.repository import trials as trial_repo

ADMIN = Principal(role=Role.admin, token_id=None)


def _study(direction: str) -> StudyCreate:
    return StudyCreate.model_validate(
        {
            "name": f"prepared-{direction}",
            "direction": direction,
            "space": {"type": "box", "params": [{"name": "x", "low": 0, "high": 1}]},
            "proposer": {"name": "random"},
            "max_trials": 6,
        }
    )


def _script(db: Database) -> list[Any]:
    """Every hot statement in every variant, and the refusals after them; returns what
    each step gave (trials, or the error's type)."""
    out: list[Any] = []
    with db.write() as session:
        owner_digest, worker_digest = "a" * 64, "b" * 64
        owner = token_repo.create_token(session, name="owner", role="user", digest=owner_digest)
        worker = token_repo.create_token(session, name="fleet", role="worker", digest=worker_digest)
        user = Principal(role=Role.user, token_id=owner.id, name="owner")
        fleet = Principal(role=Role.worker, token_id=worker.id, name="fleet")
        studies = [
            study_repo.create_study(session, body=_study(d), representation=None, owner=user).id
            for d in ("maximize", "minimize")
        ]
    for study_id in studies:
        with db.write() as session:
            first = trial_repo.reserve_numbers(session, study_id=study_id, count=4)
            out.append(first)
            asked = trial_repo.insert_trials(
                session,
                study_id=study_id,
                first_number=first,
                vectors=[[0.1 * (i + 1)] for i in range(3)],
                params=[{"x": 0.1 * (i + 1)} for i in range(3)],
                infos=[{"proposer": "random", "i": i} for i in range(3)],
            )
            leased = trial_repo.insert_trials(
                session,
                study_id=study_id,
                first_number=first + 3,
                vectors=[[0.9]],
                params=[{"x": 0.9}],
                infos=[{}],
                worker_id="w1",
                lease_token_id=worker.id,
                lease_seconds=30.0,
            )
            out += asked + leased
        tells: list[tuple[int, TellRequest, Principal]] = [
            (asked[0].id, TellRequest(value=2.0), user),
            (asked[1].id, TellRequest(value=5.0, metrics={"m": 1.5, "n": 2}), ADMIN),
            (asked[2].id, TellRequest(state="failed", message="crashed"), user),
            (asked[1].id, TellRequest(value=5.0), user),  # repeated: harmless
            (asked[1].id, TellRequest(value=6.0), user),  # contradicting: conflict
            (leased[0].id, TellRequest(value=1.0, worker_id="w2"), fleet),  # not the holder
            (leased[0].id, TellRequest(value=-1.0, worker_id="w1"), fleet),
        ]
        for trial_id, body, caller in tells:
            try:
                with db.write() as session:
                    out.append(
                        tell_repo.tell_trial(session, trial_id=trial_id, body=body, caller=caller)
                    )
            except (ConflictError, LeaseLostError) as error:
                out.append(type(error).__name__)
        with db.write() as session:  # a proposal's reservation, and its fallbacks
            reserved = trial_repo.reserve_for_proposal(session, study_id=study_id, count=1)
            out.append(reserved)
            study_repo.record_fallbacks(session, study_id=study_id, count=2, reason="budget")
        with db.write() as session:
            out.append(trial_repo.reserve_for_proposal(session, study_id=study_id, count=1))
            study_repo.record_fallbacks(session, study_id=study_id, count=0, reason=None)
        with db.write() as session:
            try:
                trial_repo.reserve_numbers(session, study_id=study_id, count=3)  # over max
            except ConflictError as error:
                out.append(str(error))
    return out


def _tables(db: Database) -> dict[str, list[dict[str, Any]]]:
    with db.engine.connect() as connection:
        return {
            table: [
                dict(row._mapping)
                for row in connection.execute(sa.text(f"SELECT * FROM {table} ORDER BY 1"))
            ]
            for table in ("studies", "trials", "workers")
        }


def _without_clock(value: Any) -> Any:
    """Times differ between the two runs; their presence and type must not."""
    if isinstance(value, Trial):
        value = value.model_dump()
    if isinstance(value, dict):
        return {key: _without_clock(item) for key, item in value.items()}
    if isinstance(value, list):
        return [_without_clock(item) for item in value]
    if isinstance(value, datetime):
        assert value.tzinfo == UTC
        return "time"
    if isinstance(value, str) and value[:2] == "20" and value[4:5] == "-" and ":" in value:
        return "time"  # a stored timestamp, read back raw
    return value


@pytest.fixture
def databases(tmp_path: Path) -> Iterator[tuple[Database, Database]]:
    pair = []
    for name in ("driver", "sqlalchemy"):
        url = f"sqlite:///{tmp_path / name}.db"
        upgrade_to_head(url)
        pair.append(Database(url, driver_statements=name == "driver"))
    yield pair[0], pair[1]
    for db in pair:
        db.dispose()


def test_the_driver_path_does_what_sqlalchemy_does(databases: tuple[Database, Database]) -> None:
    driver, through_sqlalchemy = databases
    ours, theirs = _script(driver), _script(through_sqlalchemy)
    assert [_without_clock(x) for x in ours] == [_without_clock(x) for x in theirs]
    assert "ConflictError" in ours and "LeaseLostError" in ours  # the refusals ran
    tables = _tables(driver)
    assert _without_clock(tables) == _without_clock(_tables(through_sqlalchemy))
    best = {
        row["id"]: (
            row["best_value"],
            *(
                sum(t["study_id"] == row["id"] and t["state"] == state for t in tables["trials"])
                for state in ("complete", "failed")
            ),
        )
        for row in tables["studies"]
    }
    assert best == {1: (5.0, 3, 1), 2: (-1.0, 3, 1)}
    reserved = [x for x in ours if isinstance(x, trial_repo.Reserved)]
    assert reserved == [(4, None), (5, "budget")] * 2  # the reason read back, then cleared
    assert {
        (row["proposal_fallbacks"], row["proposal_fallback_reason"], row["n_trials"])
        for row in tables["studies"]
    } == {(2, None, 6)}
    assert {row["worker_id"]: row["jobs_done"] for row in tables["workers"]} == {"w1": 2}


def test_a_statement_with_an_expanding_parameter_is_refused(
    databases: tuple[Database, Database],
) -> None:
    trials = sa.table("trials", sa.column("id"), sa.column("state"))
    expanding = Prepared(
        sa.update(trials).where(trials.c.state.in_(("queued", "running"))).values(state="failed")
    )
    with pytest.raises(TypeError, match="expands per execution"), databases[0].write() as session:
        expanding.rows(session, [{"id": 1}])
