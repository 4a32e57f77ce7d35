from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))

from robots import write_urdf

from adworker import designs


@pytest.fixture
def urdf_of(tmp_path: Path):
    """Write one of the reference designs (by function name in adworker.designs)."""

    def write(name: str, **kwargs: object) -> Path:
        design = getattr(designs, name)(**kwargs)
        return write_urdf(design, tmp_path / f"{name}.urdf")

    return write
