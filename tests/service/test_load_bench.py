"""The load driver (``adclient.testing.load``) at a small scale, on each database: it
runs and its workers lose, duplicate and strand nothing (bench/load.py's 10,000-trial
run is the benchmark)."""

from __future__ import annotations

from pathlib import Path

import pytest

from adclient.testing.load import ENDPOINTS, run_load

pytestmark = pytest.mark.e2e


def test_small_load_loses_duplicates_and_strands_nothing(database_url: str, tmp_path: Path) -> None:
    result = run_load(database_url, tmp_path, workers=6, trials=120, processes=2, limit_s=600)
    assert (result["lost"], result["duplicated"], result["stuck"]) == (0, 0, 0)
    assert result["errors"] == {}
    assert (result["stored"], result["complete"], result["study_state"]) == (120, 120, "complete")
    assert result["latency_ms"]["tell"]["n"] == 120
    assert all(result["latency_ms"][e]["p50"] > 0 for e in ENDPOINTS)
