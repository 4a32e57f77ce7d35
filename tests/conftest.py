"""Shared fixtures: real server processes on SQLite files in a temporary folder."""

from __future__ import annotations

from collections.abc import Callable, Iterator

import pytest

from tests.servers import ServerProcess


@pytest.fixture
def server_factory(
    tmp_path_factory: pytest.TempPathFactory,
) -> Iterator[Callable[..., ServerProcess]]:
    """Start real ``adserver`` processes: ``server_factory(AD_LEASE_SECONDS="2")``."""
    started: list[ServerProcess] = []

    def start(database_url: str | None = None, **env: str) -> ServerProcess:
        workdir = tmp_path_factory.mktemp("server")
        url = database_url or f"sqlite:///{workdir / 'studies.db'}"
        server = ServerProcess(database_url=url, workdir=workdir, env=env).start()
        started.append(server)
        return server

    yield start
    for server in started:
        server.stop()


@pytest.fixture
def live_server(server_factory: Callable[..., ServerProcess]) -> ServerProcess:
    """One real ``adserver`` on a fresh SQLite file; ``.url`` is its base URL."""
    return server_factory()
