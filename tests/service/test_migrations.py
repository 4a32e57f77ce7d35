"""Alembic's head on an empty database is exactly the models' schema, on SQLite and on
PostgreSQL; upgrading twice, or from several processes at once, is harmless. These tests
take databases nothing has touched (``empty_database_url``); the suite's other fresh
databases are copies of one migrated per test process, checked here too."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import sqlalchemy as sa
from alembic.autogenerate import compare_metadata
from alembic.migration import MigrationContext

from adclient.testing.forked import run_adserver
from adclient.testing.servers import ServerProcess
from adservice.db import MIGRATIONS_DIR, upgrade_to_head
from adservice.models import Base

TABLES = {
    "trial_urdfs",
    "studies",
    "trials",
    "trial_reports",
    "artifacts",
    "workers",
    "tokens",
    "alembic_version",
}
HEAD = max(path.name.split("_")[0] for path in (MIGRATIONS_DIR / "versions").glob("*.py"))


def test_upgrade_head_matches_models(empty_database_url: str) -> None:
    upgrade_to_head(empty_database_url)
    engine = sa.create_engine(empty_database_url)
    with engine.connect() as connection:
        diff = compare_metadata(MigrationContext.configure(connection), Base.metadata)
    engine.dispose()
    assert diff == []


def test_fresh_databases_are_what_migrating_from_empty_gives(
    database_url: str, empty_database_url: str
) -> None:
    """The suite's fresh databases (copies of a template migrated once per test process,
    tests/conftest.py) hold exactly the models' schema at Alembic's head and no rows,
    while an empty one holds nothing until migrated."""
    fresh, empty = sa.create_engine(database_url), sa.create_engine(empty_database_url)
    assert sa.inspect(empty).get_table_names() == []
    with fresh.connect() as connection:
        diff = compare_metadata(MigrationContext.configure(connection), Base.metadata)
        version = connection.execute(sa.text("SELECT version_num FROM alembic_version")).all()
        counts = {
            table: connection.execute(sa.text(f'SELECT count(*) FROM "{table}"')).scalar()
            for table in sorted(TABLES - {"alembic_version"})
        }
    fresh.dispose()
    empty.dispose()
    upgrade_to_head(empty_database_url)
    migrated = sa.create_engine(empty_database_url)
    with migrated.connect() as connection:
        head = connection.execute(sa.text("SELECT version_num FROM alembic_version")).all()
    migrated.dispose()
    assert diff == [] and version == head
    assert counts == dict.fromkeys(counts, 0)


def test_upgrade_is_idempotent(empty_database_url: str) -> None:
    upgrade_to_head(empty_database_url)
    upgrade_to_head(empty_database_url)
    engine = sa.create_engine(empty_database_url)
    tables = set(sa.inspect(engine).get_table_names())
    engine.dispose()
    assert tables >= TABLES


def test_adserver_migrate_brings_the_schema_to_head_and_exits(
    empty_database_url: str, tmp_path: Path
) -> None:
    """What deploy/k8s's init container runs before each server replica starts (the
    installed program, forked as the harness starts servers)."""
    output = tmp_path / "migrate.log"
    for _ in range(2):
        argv = ["migrate", "--database-url", empty_database_url]
        code = run_adserver(argv, env=os.environ, cwd=tmp_path, output=output)
        assert code == 0, output.read_text()
    engine = sa.create_engine(empty_database_url)
    tables = set(sa.inspect(engine).get_table_names())
    engine.dispose()
    assert tables >= TABLES


def test_a_server_start_says_the_schema_is_at_head_in_one_line(
    empty_database_url: str, tmp_path: Path
) -> None:
    """Issue 62: a start on a migrated database logs one line for the schema, none of
    Alembic's (about 15 INFO lines a start before); the first start, which migrates,
    says so and logs each revision it runs."""
    logs = []
    for run in ("first", "again"):
        (tmp_path / run).mkdir()
        server = ServerProcess(
            database_url=empty_database_url, workdir=tmp_path / run, log_level="info"
        ).start()
        server.stop()
        logs.append(server.log().splitlines())
    migrating, at_head = logs
    (head,) = [line for line in at_head if "adservice.db" in line]
    assert head.endswith(
        f"INFO adservice.db database schema at head (revision {HEAD}): nothing to migrate"
    )
    assert not [line for line in at_head if "alembic" in line]
    (said,) = [line for line in migrating if "adservice.db" in line]
    assert said.endswith(f"migrating the database schema from an empty database to revision {HEAD}")
    ran = [line for line in migrating if "alembic.runtime.migration Running upgrade" in line]
    assert len(ran) == len(list((MIGRATIONS_DIR / "versions").glob("*.py")))
    assert not [line for line in migrating if "alembic.runtime.plugins" in line]


@pytest.mark.postgres
def test_processes_starting_at_once_migrate_one_after_the_other(
    new_empty_postgres_url: Callable[[], str],
) -> None:
    """Several servers started together on one PostgreSQL database all come up."""
    url = new_empty_postgres_url()
    script = "import sys; from adservice.db import upgrade_to_head; upgrade_to_head(sys.argv[1])"
    processes = [
        subprocess.Popen([sys.executable, "-c", script, url], stderr=subprocess.PIPE, text=True)
        for _ in range(4)
    ]
    errors = [(p.communicate()[1][-2000:], p.returncode) for p in processes]
    assert [error for error, code in errors if code != 0] == []
    engine = sa.create_engine(url)
    with engine.connect() as connection:
        versions = connection.execute(sa.text("SELECT count(*) FROM alembic_version")).scalar()
        tables = set(sa.inspect(connection).get_table_names())
    engine.dispose()
    assert versions == 1 and tables >= TABLES


def _alembic(url: str) -> Any:
    from alembic.config import Config

    from adservice.db import MIGRATIONS_DIR

    config = Config()
    config.set_main_option("script_location", str(MIGRATIONS_DIR))
    config.set_main_option("sqlalchemy.url", url.replace("%", "%%"))
    return config


def test_0005_gives_old_studies_no_pruner_and_goes_back_down(empty_database_url: str) -> None:
    """A study stored before pruning reads as ``pruner: none`` with 0 pruned; the
    reports table comes and goes with the revision."""
    from alembic import command

    config = _alembic(empty_database_url)
    command.upgrade(config, "0004")
    engine = sa.create_engine(empty_database_url)
    with engine.begin() as connection:
        connection.execute(
            sa.text(
                "INSERT INTO studies (name, direction, state, space, proposer, max_attempts,"
                " n_trials, n_complete, n_failed, metadata, created_at, updated_at) VALUES"
                " ('old', 'maximize', 'running', '{}', '{}', 3, 0, 0, 0, '{}',"
                " '2024-01-01 00:00:00', '2024-01-01 00:00:00')"
            )
        )
    command.upgrade(config, "0013")  # 0014 drops the counter: counts come from the trials
    with engine.connect() as connection:
        pruner, pruned = connection.execute(
            sa.text("SELECT pruner, n_pruned FROM studies WHERE name = 'old'")
        ).one()
        assert "trial_reports" in sa.inspect(connection).get_table_names()
    assert (json.loads(pruner) if isinstance(pruner, str) else pruner) == {"name": "none"}
    assert pruned == 0
    command.downgrade(config, "0004")
    with engine.connect() as connection:
        assert "trial_reports" not in sa.inspect(connection).get_table_names()
        columns = {c["name"] for c in sa.inspect(connection).get_columns("studies")}
    engine.dispose()
    assert "n_pruned" not in columns and "pruner" not in columns


def _old_study(connection: sa.Connection, states: list[str]) -> None:
    """A study as stored from 0005 to 0013 (its counters at 0), with a trial in each
    of ``states``, numbered in order."""
    connection.execute(
        sa.text(
            "INSERT INTO studies (name, direction, state, space, proposer, pruner,"
            " max_attempts, n_trials, n_complete, n_failed, n_pruned, metadata,"
            " created_at, updated_at) VALUES ('old', 'maximize', 'running', '{}', '{}',"
            " '{}', 3, :n, 0, 0, 0, '{}', '2024-01-01 00:00:00', '2024-01-01 00:00:00')"
        ),
        {"n": len(states)},
    )
    for number, state in enumerate(states):
        connection.execute(
            sa.text(
                "INSERT INTO trials (study_id, number, state, vector, params, metrics, info,"
                " attempts, created_at) SELECT id, :number, :state, '[]', '{}', '{}', '{}', 0,"
                " '2024-01-01 00:00:00' FROM studies"
            ),
            {"number": number, "state": state},
        )


def test_0007_gives_old_rows_no_user_attrs_and_goes_back_down(empty_database_url: str) -> None:
    """Rows stored before 0007 read as having no user attributes; going back down keeps
    each study, its name cut to the old column's 128 characters."""
    from alembic import command

    config = _alembic(empty_database_url)
    command.upgrade(config, "0006")
    engine = sa.create_engine(empty_database_url)
    with engine.begin() as connection:
        _old_study(connection, ["queued"])
    command.upgrade(config, "head")
    with engine.begin() as connection:
        studies = connection.execute(sa.text("SELECT user_attrs FROM studies")).scalars().all()
        trials = connection.execute(sa.text("SELECT user_attrs FROM trials")).scalars().all()
        connection.execute(sa.text("UPDATE studies SET name = :name"), {"name": "設計" * 100})
    assert [json.loads(a) if isinstance(a, str) else a for a in studies + trials] == [{}, {}]
    command.downgrade(config, "0006")
    with engine.connect() as connection:
        assert connection.execute(sa.text("SELECT name FROM studies")).scalar() == "設計" * 64
        columns = {c["name"] for c in sa.inspect(connection).get_columns("trials")}
        assert connection.execute(sa.text("SELECT count(*) FROM trials")).scalar() == 1
    engine.dispose()
    assert "user_attrs" not in columns


def test_0014_drops_the_study_counters_and_going_down_counts_the_trials(
    empty_database_url: str,
) -> None:
    """A study's complete, failed and pruned counts are its trials' states from 0014 on;
    going back down gives the study its counters again, counted from its trials."""
    from alembic import command

    config = _alembic(empty_database_url)
    command.upgrade(config, "0013")
    engine = sa.create_engine(empty_database_url)
    with engine.begin() as connection:
        _old_study(connection, ["complete", "complete", "failed", "pruned", "complete", "running"])
    command.upgrade(config, "head")
    with engine.connect() as connection:
        columns = {c["name"] for c in sa.inspect(connection).get_columns("studies")}
    assert not {"n_complete", "n_failed", "n_pruned"} & columns
    assert "n_trials" in columns
    command.downgrade(config, "0013")
    with engine.connect() as connection:
        counts = connection.execute(
            sa.text("SELECT n_complete, n_failed, n_pruned, n_trials FROM studies")
        ).one()
    engine.dispose()
    assert tuple(counts) == (3, 1, 1, 6)


def test_0016_adds_notes_that_go_with_their_study_and_trial_and_goes_back_down(
    empty_database_url: str,
) -> None:
    """Stored studies have no notes from 0016 on; a note names its study, and a trial's
    its trial, each going with it (ON DELETE CASCADE); going back down drops the notes and
    keeps the studies and trials."""
    from alembic import command

    config = _alembic(empty_database_url)
    command.upgrade(config, "0013")
    engine = sa.create_engine(empty_database_url)
    with engine.begin() as connection:
        _old_study(connection, ["complete"])
    command.upgrade(config, "head")
    with engine.begin() as connection:
        assert connection.execute(sa.text("SELECT count(*) FROM notes")).scalar() == 0
        connection.execute(
            sa.text(
                "INSERT INTO notes (study_id, trial_id, text, updated_at) SELECT study_id, id,"
                " 'ran hot', '2024-01-02 00:00:00' FROM trials"
            )
        )
        keys = sa.inspect(connection).get_foreign_keys("notes")
    assert sorted((key["referred_table"], key["options"].get("ondelete")) for key in keys) == [
        ("studies", "CASCADE"),
        ("trials", "CASCADE"),
    ]
    command.downgrade(config, "0015")
    with engine.connect() as connection:
        assert "notes" not in sa.inspect(connection).get_table_names()
        assert connection.execute(sa.text("SELECT count(*) FROM trials")).scalar() == 1
    engine.dispose()
