"""Shared fixtures: real server processes, and databases of each kind the service runs on.

Tests that ask for ``database_url``, ``new_database_url``, ``server_factory``,
``live_server`` or ``shared_server`` run twice: on a SQLite file and on a throwaway
PostgreSQL cluster (one per test process, started on first use; see ``adclient.testing.postgres``).
Each test gets fresh databases; ``shared_server`` is one server per test module and kind
of database. ``browser`` is a page of a headless Chromium started once per test process,
in a browser context of its own.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator

import pytest

from adclient.testing.postgres import PostgresCluster, PostgresUnavailable
from adclient.testing.servers import ServerProcess
from tests.service.chromium import Chromium, SharedChromium, find_chromium
from tests.system_packages import unavailable

DATABASES = ["sqlite", pytest.param("postgresql", marks=pytest.mark.postgres)]


@pytest.fixture(scope="session")
def postgres_cluster() -> Iterator[PostgresCluster]:
    """One PostgreSQL cluster per test process (so per xdist worker), stopped at the end;
    without PostgreSQL its tests skip, or fail where required (tests/system_packages.py)."""
    try:
        cluster = PostgresCluster.start(durable=False)
    except PostgresUnavailable as error:
        unavailable("POSTGRESQL", str(error))
    yield cluster
    cluster.stop()


@pytest.fixture(params=DATABASES)
def database(request: pytest.FixtureRequest) -> str:
    """The kind of database under test: "sqlite" or "postgresql"."""
    return str(request.param)


@pytest.fixture
def new_postgres_url(postgres_cluster: PostgresCluster) -> Iterator[Callable[[], str]]:
    """Make fresh empty PostgreSQL databases (for tests of PostgreSQL alone); each is
    dropped after the test."""
    made: list[str] = []

    def make() -> str:
        made.append(postgres_cluster.create_database())
        return made[-1]

    yield make
    for url in made:
        postgres_cluster.drop_database(url)


@pytest.fixture
def new_database_url(
    database: str, tmp_path_factory: pytest.TempPathFactory, request: pytest.FixtureRequest
) -> Callable[[], str]:
    """Make fresh empty databases of the kind under test: ``new_database_url()``."""
    if database == "postgresql":
        return request.getfixturevalue("new_postgres_url")
    return lambda: f"sqlite:///{tmp_path_factory.mktemp('db') / 'studies.db'}"


@pytest.fixture
def database_url(new_database_url: Callable[[], str]) -> str:
    """A fresh empty database of the kind under test."""
    return new_database_url()


@pytest.fixture
def server_factory(
    tmp_path_factory: pytest.TempPathFactory, new_database_url: Callable[[], str]
) -> Iterator[Callable[..., ServerProcess]]:
    """Start real ``adserver`` processes: ``server_factory(AD_LEASE_SECONDS="2")``; each
    on a fresh database of the kind under test unless given ``database_url``."""
    started: list[ServerProcess] = []

    def start(database_url: str | None = None, **env: str) -> ServerProcess:
        workdir = tmp_path_factory.mktemp("server")
        url = database_url or new_database_url()
        server = ServerProcess(database_url=url, workdir=workdir, env=env).start()
        started.append(server)
        return server

    yield start
    for server in started:
        server.stop()


@pytest.fixture
def live_server(server_factory: Callable[..., ServerProcess]) -> ServerProcess:
    """One real ``adserver`` on a fresh database; ``.url`` is its base URL."""
    return server_factory()


@pytest.fixture(scope="module", params=DATABASES)
def shared_server(
    request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[ServerProcess]:
    """One real ``adserver`` per test module and kind of database (sqlite, postgresql),
    shared by the module's tests that ask for it: for tests that make studies of their
    own and look only at those (or at what they added). A test that needs an empty
    server, leases a job of any study, or stops or changes the server takes
    ``live_server``."""
    if request.param == "postgresql":
        cluster: PostgresCluster = request.getfixturevalue("postgres_cluster")
        url = cluster.create_database()
    else:
        url = f"sqlite:///{tmp_path_factory.mktemp('db') / 'studies.db'}"
    server = ServerProcess(database_url=url, workdir=tmp_path_factory.mktemp("server"))
    try:
        yield server.start()
    finally:
        server.stop()
        if request.param == "postgresql":
            cluster.drop_database(url)


@pytest.fixture(scope="session")
def chromium_executable() -> str:
    return find_chromium()


@pytest.fixture(scope="session")
def shared_chromium(
    chromium_executable: str, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[SharedChromium]:
    """One headless Chromium per test process (restarted if it dies or hangs)."""
    shared = SharedChromium(chromium_executable, tmp_path_factory.mktemp("chromium"))
    yield shared
    shared.close()


@pytest.fixture
def browser(shared_chromium: SharedChromium) -> Iterator[Chromium]:
    """A page for one test, in a fresh browser context of the shared Chromium: cookies,
    storage and cache of its own, as a new profile's. A test that needs a whole browser
    (a profile on disk, flags, a restart) makes its own ``Chromium``."""
    page = shared_chromium.page()
    yield page
    page.close()
