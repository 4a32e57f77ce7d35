"""The 8-tree, 13-spec ask through HTTP at n = 27 to 29 (issue 37), and where it goes.

For each of ``additive-trap`` and ``shifted-optima`` (``--objectives``; the 8-tree
space) and each seed, a study on a real ``adserver`` (SQLite file, loopback HTTP)
with the default ``qei`` asks and tells 30 designs one at a time, as
bench/design_suite.py does; the last three asks are timed and their trials' info read:
the proposer's fit and acquisition seconds and its thread CPU seconds, so the rest of
the wall time is the server's and HTTP's. The code measured is whatever is first on
PYTHONPATH (the server inherits it): run it once per checkout to compare two, or
through bench/compare.py, which alternates two checkouts' runs and collects the medians
this prints as ``BENCH`` lines (wall, fit, acquisition and proposer CPU seconds).

Run: ``OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 .venv/bin/python bench/design_asklatency.py``
(``--seeds 2``); against main, alternating:
``OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 .venv/bin/python bench/compare.py --baseline main
--runs 5 -- bench/design_asklatency.py``.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import httpx
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from adclient.design import DesignSpace  # noqa: E402
from adclient.testing.design_objectives import OBJECTIVES  # noqa: E402
from adclient.testing.figures import emit  # noqa: E402
from adclient.testing.servers import ServerProcess  # noqa: E402
from bench.design_suite import BUDGET, design_from_params  # noqa: E402

LATE = 3
"""The asks timed: the last ones of the budget (n = 27 to 29)."""


def late_asks(http: httpx.Client, name: str, seed: int) -> list[list[float]]:
    """One study of the objective: per late ask, wall, fit, acquisition and CPU seconds."""
    objective = OBJECTIVES[name]
    parsed = DesignSpace.model_validate(objective.space)
    created = http.post(
        "/api/v1/studies",
        json={
            "name": f"latency-{name}-{seed}-{time.time_ns()}",
            "direction": "maximize",
            "space": objective.space,
            "proposer": {"name": "qei", "seed": seed},
            "max_trials": BUDGET,
        },
    )
    created.raise_for_status()
    study_id = created.json()["id"]
    rows = []
    for n in range(BUDGET):
        started = time.perf_counter()
        asked = http.post(f"/api/v1/studies/{study_id}/ask", json={"count": 1})
        wall = time.perf_counter() - started
        asked.raise_for_status()
        (trial,) = asked.json()["trials"]
        if n >= BUDGET - LATE:
            info = trial.get("info") or {}
            rows.append(
                [wall]
                + [
                    float(info.get(key, np.nan))
                    for key in ("fit_seconds", "acq_seconds", "cpu_seconds")
                ]
            )
        value = objective.score(design_from_params(parsed, trial["params"]))
        http.post(f"/api/v1/trials/{trial['id']}/tell", json={"value": value}).raise_for_status()
    return rows


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=2)
    parser.add_argument("--objectives", nargs="+", default=["additive-trap", "shifted-optima"])
    args = parser.parse_args()
    rows: list[list[float]] = []
    with tempfile.TemporaryDirectory() as workdir:
        server = ServerProcess(
            database_url=f"sqlite:///{workdir}/latency.db", workdir=Path(workdir)
        ).start()
        try:
            with httpx.Client(base_url=server.url, timeout=300) as http:
                for name in args.objectives:
                    for seed in range(args.seeds):
                        rows += late_asks(http, name, seed)
        finally:
            server.stop()
    wall, fit, acquisition, cpu = np.nanmedian(np.array(rows), axis=0)
    print(
        f"{len(rows)} asks at n = {BUDGET - LATE} to {BUDGET - 1}, medians: wall {wall:.3f} s, "
        f"fit {fit:.3f} s, acquisition {acquisition:.3f} s, proposer CPU {cpu:.3f} s"
    )
    for metric, value in (
        ("ask wall", wall),
        ("fit", fit),
        ("acquisition", acquisition),
        ("proposer CPU", cpu),
    ):
        emit(metric, float(value), higher_is_better=False, unit="s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
