"""Shared fixtures: real server processes, and databases of each kind the service runs on.

Tests that ask for ``database_url``, ``new_database_url``, ``server_factory``,
``live_server`` or ``shared_server`` run twice: on a SQLite file and on a throwaway
PostgreSQL cluster (one per test process, started on first use; see ``adclient.testing.postgres``).
Each test gets fresh databases; ``shared_server`` is one server per test module and kind
of database. ``browser`` is the one page of a headless Chromium started once per test process
that the process's tests take in turn, blank and with nothing kept at each take.

A fresh database is a copy of a template that each test process migrates once, with
this checkout's migrations, on first use: a SQLite file copied, a PostgreSQL database
made ``TEMPLATE`` the migrated one. It holds the schema at head and no rows, what
migrating an empty database gives, so a server started on it finds nothing to
migrate; migrating from empty on every one of the suite's hundreds of databases cost
about a quarter of a second of CPU each. The migrations stay tested from empty: tests
of migrating, of an empty database or of a server's first start (tests/service/
test_migrations.py, the README's quick start, two servers that migrate at once) ask
for ``empty_database_url``, ``new_empty_database_url`` or ``new_empty_postgres_url``,
which give databases nothing has touched; tests/test_wheel.py makes its own.
"""

from __future__ import annotations

import contextlib
import os
import shutil
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from adclient.testing.postgres import PostgresCluster, PostgresUnavailable
from adclient.testing.servers import ServerProcess
from tests.service.chromium import Chromium, SharedChromium, find_chromium, leave
from tests.system_packages import unavailable

DATABASES = ["sqlite", pytest.param("postgresql", marks=pytest.mark.postgres)]


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """A test marked ``alone`` compares latencies, which other tests running beside it
    would set: under several test processes it is skipped, saying so (``make test``
    runs the ``alone`` tests after the others, in one process)."""
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))  # set in xdist's workers
    if workers <= 1:
        return
    skip = pytest.mark.skip(
        reason="SKIPPED LOUDLY: an `alone` test measures latency and is run with no other "
        f"test beside it, not among {workers} test processes: run `pytest -m alone` "
        "(make test does, after the others)"
    )
    for item in items:
        if item.get_closest_marker("alone") is not None:
            item.add_marker(skip)


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


@pytest.fixture(scope="session")
def postgres_template(postgres_cluster: PostgresCluster) -> str:
    """A PostgreSQL database migrated to head once per test process, for copying."""
    from adservice.db import upgrade_to_head

    return postgres_cluster.create_template(upgrade_to_head)


@pytest.fixture(scope="session")
def sqlite_template(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A SQLite file migrated to head once per test process, for copying."""
    from adservice.db import upgrade_to_head

    path = tmp_path_factory.mktemp("template") / "studies.db"
    upgrade_to_head(f"sqlite:///{path}")
    return path


def _sqlite_copy(template: Path, tmp_path_factory: pytest.TempPathFactory) -> str:
    path = tmp_path_factory.mktemp("db") / "studies.db"
    shutil.copyfile(template, path)
    return f"sqlite:///{path}"


@pytest.fixture
def new_sqlite_url(
    sqlite_template: Path, tmp_path_factory: pytest.TempPathFactory
) -> Callable[[], str]:
    """Make fresh SQLite files at the schema's head, with no rows (for tests of SQLite
    alone): ``new_sqlite_url()``."""
    return lambda: _sqlite_copy(sqlite_template, tmp_path_factory)


def _postgres_maker(cluster: PostgresCluster, template: str | None) -> Iterator[Callable[[], str]]:
    made: list[str] = []

    def make() -> str:
        made.append(cluster.create_database(template=template))
        return made[-1]

    yield make
    for url in made:
        cluster.drop_database(url)


@pytest.fixture
def new_postgres_url(
    postgres_cluster: PostgresCluster, postgres_template: str
) -> Iterator[Callable[[], str]]:
    """Make fresh PostgreSQL databases at the schema's head, with no rows (for tests of
    PostgreSQL alone); each is dropped after the test."""
    yield from _postgres_maker(postgres_cluster, postgres_template)


@pytest.fixture
def new_empty_postgres_url(postgres_cluster: PostgresCluster) -> Iterator[Callable[[], str]]:
    """Make fresh PostgreSQL databases with nothing in them, not even a schema (for tests
    of migrating); each is dropped after the test."""
    yield from _postgres_maker(postgres_cluster, None)


@pytest.fixture
def new_database_url(
    database: str, tmp_path_factory: pytest.TempPathFactory, request: pytest.FixtureRequest
) -> Callable[[], str]:
    """Make fresh databases of the kind under test, at the schema's head with no rows:
    ``new_database_url()``."""
    if database == "postgresql":
        return request.getfixturevalue("new_postgres_url")
    return request.getfixturevalue("new_sqlite_url")


@pytest.fixture
def database_url(new_database_url: Callable[[], str]) -> str:
    """A fresh database of the kind under test, at the schema's head with no rows."""
    return new_database_url()


@pytest.fixture
def new_empty_database_url(
    database: str, tmp_path_factory: pytest.TempPathFactory, request: pytest.FixtureRequest
) -> Callable[[], str]:
    """Make fresh databases of the kind under test that nothing has touched (no schema,
    no migration): for tests of migrating and of a server's first start."""
    if database == "postgresql":
        return request.getfixturevalue("new_empty_postgres_url")
    return lambda: f"sqlite:///{tmp_path_factory.mktemp('db') / 'studies.db'}"


@pytest.fixture
def empty_database_url(new_empty_database_url: Callable[[], str]) -> str:
    """A fresh database of the kind under test that nothing has touched."""
    return new_empty_database_url()


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
    with module_server(request, tmp_path_factory, "server") as server:
        yield server


@contextlib.contextmanager
def module_server(
    request: pytest.FixtureRequest,
    tmp_path_factory: pytest.TempPathFactory,
    folder: str,
    env: dict[str, str] | None = None,
) -> Iterator[ServerProcess]:
    """A started ``adserver`` (with ``env``) on a copy of the migrated template of the
    module fixture's database (``request.param``: sqlite or postgresql), stopped and its
    database dropped at the end: what a module-scoped server fixture yields."""
    if request.param == "postgresql":
        cluster: PostgresCluster = request.getfixturevalue("postgres_cluster")
        url = cluster.create_database(template=request.getfixturevalue("postgres_template"))
    else:
        url = _sqlite_copy(request.getfixturevalue("sqlite_template"), tmp_path_factory)
    server = ServerProcess(database_url=url, workdir=tmp_path_factory.mktemp(folder), env=env or {})
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
    """The page the test process's tests take in turn (``SharedChromium.shared_page``):
    blank at each take, with no cookies, storage or cache kept and nothing recorded, as
    a new profile's (a dashboard visit there costs about 0.8 s of Chromium's CPU, in a
    new browser context 1.5 s); left blank before the test's server stops. A test that
    needs a whole browser (a profile on disk, flags, a restart) makes its own
    ``Chromium``."""
    page = shared_chromium.shared_page()
    yield page
    leave(page)
