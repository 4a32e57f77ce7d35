"""Fixtures shared by the SDK and CLI tests."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from adclient import Client
from adclient.testing.servers import ServerProcess


@pytest.fixture
def client(server: ServerProcess) -> Iterator[Client]:
    """An SDK client on the test module's own ``server`` fixture, quick to retry."""
    with Client(server.url, retries=2, backoff=0.05) as api:
        yield api
