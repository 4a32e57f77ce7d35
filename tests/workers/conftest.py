from __future__ import annotations

from pathlib import Path

import pytest

from adworker import designs
from tests.workers.robots import write_urdf


@pytest.fixture
def urdf_of(tmp_path: Path):
    """Write one of the reference designs (by function name in adworker.designs)."""

    def write(name: str, **kwargs: object) -> Path:
        design = getattr(designs, name)(**kwargs)
        return write_urdf(design, tmp_path / f"{name}.urdf")

    return write
