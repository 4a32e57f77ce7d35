"""The test harness's throwaway PostgreSQL (``adclient.testing.postgres``): a fresh database
is a copy of the migrated template, made by copying its files."""

from __future__ import annotations

import psycopg
import pytest

from adclient.testing.postgres import PostgresCluster

pytestmark = pytest.mark.postgres

MIB = 2**20


def test_a_copy_of_the_template_has_its_schema_and_writes_almost_no_wal(
    postgres_cluster: PostgresCluster, postgres_template: str
) -> None:
    """Copied block by block through the WAL (PostgreSQL 15's default), each of the
    suite's hundreds of databases wrote all of its several MiB there, catalogs included."""
    with psycopg.connect(postgres_cluster.dsn("postgres"), autocommit=True) as connection:
        start = connection.execute("SELECT pg_current_wal_insert_lsn()").fetchone()
        url = postgres_cluster.create_database(template=postgres_template)
        written = connection.execute(
            "SELECT pg_wal_lsn_diff(pg_current_wal_insert_lsn(), %s)", start
        ).fetchone()
    try:
        assert written is not None and written[0] < MIB
        copy = url.rsplit("/", 1)[1]
        with psycopg.connect(postgres_cluster.dsn(copy)) as connection:
            (version,) = connection.execute("SELECT version_num FROM alembic_version").fetchall()
            assert connection.execute("SELECT count(*) FROM studies").fetchone() == (0,)
        assert version[0]
    finally:
        postgres_cluster.drop_database(url)
