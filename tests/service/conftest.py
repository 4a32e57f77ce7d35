"""In-process app on a real database (SQLite file, then PostgreSQL: see ``database_url``),
for contract tests that need no separate process; two server processes on one PostgreSQL.
The browser tests' Chromium is tests/conftest.py's."""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from pathlib import Path

import httpx
import pytest
from fastapi.testclient import TestClient

from adclient.testing.servers import SDK_HEADERS, ServerProcess
from adservice.app import create_app
from adservice.settings import Settings
from tests.conftest import DATABASES

LOCAL = "http://localhost"
"""The in-process app answers only Host names it is served under (loopback by default)."""


@pytest.fixture
def settings(tmp_path: Path, database_url: str) -> Settings:
    return Settings(
        database_url=database_url, artifact_dir=tmp_path / "artifacts", sweep_seconds=0.2
    )


@pytest.fixture
def api(settings: Settings) -> Iterator[TestClient]:
    with TestClient(create_app(settings), base_url=LOCAL, headers=SDK_HEADERS) as client:
        yield client


BOX_STUDY = {
    "name": "box",
    "direction": "maximize",
    "space": {
        "type": "box",
        "params": [{"name": "x", "low": -1.0, "high": 1.0}, {"name": "y", "low": 0, "high": 5}],
    },
    "proposer": {"name": "random", "seed": 3},
}


@pytest.fixture
def two_servers(
    new_empty_postgres_url: Callable[[], str], tmp_path: Path
) -> Iterator[tuple[ServerProcess, ServerProcess]]:
    """Two servers on one fresh empty database, started at the same time (both migrate)."""
    url = new_empty_postgres_url()
    servers = [
        ServerProcess(database_url=url, workdir=tmp_path, env={"AD_LEASE_SECONDS": "120"})
        for _ in range(2)
    ]
    starters = [threading.Thread(target=server.start) for server in servers]
    for starter in starters:
        starter.start()
    for starter in starters:
        starter.join()
    try:
        for server in servers:
            assert httpx.get(f"{server.url}/healthz", timeout=10).status_code == 200
        yield servers[0], servers[1]
    finally:
        for server in servers:
            server.stop()


@pytest.fixture(scope="module")
def http(server: ServerProcess) -> Iterator[httpx.Client]:
    """An SDK-headed HTTP client on the test module's own ``server`` fixture, for the
    module's tests and its module-scoped data (a module without ``server`` defines its
    own ``http``)."""
    with httpx.Client(base_url=server.url, headers=SDK_HEADERS, timeout=30) as client:
        yield client


@pytest.fixture(scope="module")
def module_http(tmp_path_factory: pytest.TempPathFactory) -> Iterator[httpx.Client]:
    """A real adserver on a SQLite file of its own, shared by one module's tests (each
    looks at the studies it made), reached over HTTP."""
    work = tmp_path_factory.mktemp("module-server")
    server = ServerProcess(database_url=f"sqlite:///{work / 'studies.db'}", workdir=work).start()
    try:
        with httpx.Client(base_url=server.url, timeout=300) as client:
            yield client
    finally:
        server.stop()


@pytest.fixture(scope="module", params=DATABASES)
def secured(
    request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[ServerProcess]:
    """One real adserver with auth on per kind of database, shared by a module's tests
    that take it (each makes studies and tokens of its own)."""
    workdir = tmp_path_factory.mktemp("secured")
    if request.param == "postgresql":
        url = request.getfixturevalue("postgres_cluster").create_database()
    else:
        url = f"sqlite:///{workdir / 'studies.db'}"
    server = ServerProcess(database_url=url, workdir=workdir, env={"AD_AUTH": "true"})
    yield server.start()
    server.stop()
