"""Fixtures shared by the SDK and CLI tests."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from adclient import Client
from adclient.testing.servers import ServerProcess


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    """A real adserver on a SQLite file of its own for the test module (a module that
    needs another defines its own ``server``)."""
    workdir = tmp_path_factory.mktemp("cli-server")
    process = ServerProcess(
        database_url=f"sqlite:///{workdir / 'studies.db'}", workdir=workdir
    ).start()
    yield process
    process.stop()


@pytest.fixture
def client(server: ServerProcess) -> Iterator[Client]:
    """An SDK client on the test module's own ``server`` fixture, quick to retry."""
    with Client(server.url, retries=2, backoff=0.05) as api:
        yield api
