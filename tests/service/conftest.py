"""In-process app on a real database (SQLite file, then PostgreSQL: see ``database_url``),
for contract tests that need no separate process."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from adservice.app import create_app
from adservice.settings import Settings
from tests.servers import SDK_HEADERS

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
