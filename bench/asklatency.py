"""Ask latency of ``qei`` through HTTP, next to Optuna GPSampler's per-trial sampling time.

For every n (observations), d (dimensions) and q (points per ask) the benchmark runs
``--rounds`` rounds. Each round creates a study on a real ``adserver`` (SQLite file,
loopback HTTP, httpx) with ``qei`` and ``n_initial = n``, asks n Sobol trials (in
asks of at most 64) and tells them a smooth test function plus a little per-round
noise, then times one ``POST /ask {"count": q}``: the first model-based ask of a
study holding exactly n observations. Every round's study has the same bounds and
seed, so from the second round on the fit is warm-started from the previous round's
hyperparameters, as the next ask of a running study is; the first round is a cold
start and is part of the figures.

GPSampler runs in-process (no HTTP) on the same data: per (n, d), one sampler, a
fresh in-memory study per round holding the round's n observations, and
``study.ask()`` timed (q = 4: four consecutive asks, which is what a batch costs
there). The ratio is qei's median over GPSampler's.

Run: ``.venv/bin/python bench/asklatency.py`` (writes bench/RESULTS.md);
``--rounds 3 --no-write`` while developing.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
import warnings
from pathlib import Path

import httpx
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from adclient.testing.servers import ServerProcess  # noqa: E402
from bench.proposer_results import write_subsection  # noqa: E402

MAX_ASK = 64


def objective(unit: np.ndarray) -> np.ndarray:
    """A smooth, mildly multimodal function of points in the unit box (to be maximised)."""
    unit = np.atleast_2d(unit)
    return -np.sum((unit - 0.3) ** 2, axis=1) + 0.2 * np.sin(5.0 * np.sum(unit, axis=1))


def bounds_for(dim: int) -> np.ndarray:
    """Boxes of unequal sides, so the service's scaling is exercised."""
    return np.array([[-1.0 * (i + 1) for i in range(dim)], [2.0 * (i + 1) for i in range(dim)]])


def percentile(values: list[float], q: float) -> float:
    return float(np.percentile(np.array(values), q))


class QeiRounds:
    def __init__(self, http: httpx.Client) -> None:
        self.http = http
        self.created = 0

    def one_round(self, n: int, dim: int, q: int, round_seed: int) -> tuple[float, dict, list]:
        """Fill a fresh study with n observations, time one ask of q: (seconds, info, data)."""
        bounds = bounds_for(dim)
        self.created += 1
        study = self.http.post(
            "/api/v1/studies",
            json={
                "name": f"latency-n{n}-d{dim}-q{q}-r{self.created}",
                "direction": "maximize",
                "space": {
                    "type": "box",
                    "params": [
                        {"name": f"x{i}", "low": bounds[0, i], "high": bounds[1, i]}
                        for i in range(dim)
                    ],
                },
                "proposer": {"name": "qei", "n_initial": n, "seed": 0},
            },
        )
        study.raise_for_status()
        study_id = study.json()["id"]
        noise = np.random.default_rng([n, dim, q, round_seed])
        data: list[tuple[list[float], float]] = []
        while len(data) < n:
            asked = self.http.post(
                f"/api/v1/studies/{study_id}/ask", json={"count": min(MAX_ASK, n - len(data))}
            )
            asked.raise_for_status()
            for trial in asked.json()["trials"]:
                vector = np.array(trial["vector"])
                unit = (vector - bounds[0]) / (bounds[1] - bounds[0])
                value = float(objective(unit)[0] + 0.01 * noise.normal())
                told = self.http.post(f"/api/v1/trials/{trial['id']}/tell", json={"value": value})
                told.raise_for_status()
                data.append((trial["vector"], value))
        started = time.perf_counter()
        asked = self.http.post(f"/api/v1/studies/{study_id}/ask", json={"count": q})
        seconds = time.perf_counter() - started
        asked.raise_for_status()
        trials = asked.json()["trials"]
        assert len(trials) == q
        info = trials[0].get("info") or {}
        return seconds, info, data


def gp_optuna_seconds(sampler, dim: int, q: int, data: list) -> float:
    import optuna

    bounds = bounds_for(dim)
    distributions = {
        f"x{i}": optuna.distributions.FloatDistribution(float(bounds[0, i]), float(bounds[1, i]))
        for i in range(dim)
    }
    study = optuna.create_study(direction="maximize", sampler=sampler)
    study.add_trials(
        [
            optuna.trial.create_trial(
                params={f"x{i}": float(v) for i, v in enumerate(vector)},
                distributions=distributions,
                value=value,
            )
            for vector, value in data
        ]
    )
    started = time.perf_counter()
    for _ in range(q):
        study.ask(distributions)
    return time.perf_counter() - started


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--rounds", type=int, default=10)
    parser.add_argument("--n", nargs="+", type=int, default=[10, 50, 200])
    parser.add_argument("--d", nargs="+", type=int, default=[2, 6, 12])
    parser.add_argument("--q", nargs="+", type=int, default=[1, 4])
    parser.add_argument("--no-gp-optuna", action="store_true")
    parser.add_argument("--no-write", action="store_true", help="print only")
    args = parser.parse_args()

    import optuna

    optuna.logging.set_verbosity(optuna.logging.ERROR)
    warnings.simplefilter("ignore")
    started_all = time.perf_counter()
    rows = [
        "| n | d | q | qei median (s) | qei p95 (s) | GPSampler median (s) | GPSampler p95 (s) "
        "| ratio qei/GP | qei fit / acq median (s) | qei CPU median (s) |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    with tempfile.TemporaryDirectory() as workdir:
        server = ServerProcess(
            database_url=f"sqlite:///{Path(workdir) / 'latency.db'}", workdir=Path(workdir)
        ).start()
        try:
            with httpx.Client(base_url=server.url, timeout=300) as http:
                rounds = QeiRounds(http)
                for n in args.n:
                    for dim in args.d:
                        for q in args.q:
                            qei: list[float] = []
                            parts: list[tuple[float, float]] = []
                            gp: list[float] = []
                            sampler = optuna.samplers.GPSampler(seed=0)
                            for r in range(args.rounds):
                                seconds, info, data = rounds.one_round(n, dim, q, r)
                                qei.append(seconds)
                                if "fit_seconds" in info:
                                    parts.append(
                                        (
                                            info["fit_seconds"],
                                            info["acq_seconds"],
                                            info["cpu_seconds"],
                                        )
                                    )
                                if not args.no_gp_optuna:
                                    gp.append(gp_optuna_seconds(sampler, dim, q, data))
                            qei_median = percentile(qei, 50)
                            gp_median = percentile(gp, 50) if gp else float("nan")
                            split = (
                                f"{np.median([p[0] for p in parts]):.3f} / "
                                f"{np.median([p[1] for p in parts]):.3f} | "
                                f"{np.median([p[2] for p in parts]):.3f}"
                                if parts
                                else "- | -"
                            )
                            row = (
                                f"| {n} | {dim} | {q} | {qei_median:.3f} | "
                                f"{percentile(qei, 95):.3f} | {gp_median:.3f} | "
                                f"{percentile(gp, 95) if gp else float('nan'):.3f} | "
                                f"{qei_median / gp_median:.2f} | {split} |"
                            )
                            rows.append(row)
                            print(row, flush=True)
        finally:
            server.stop()
    elapsed = time.perf_counter() - started_all
    command = "`.venv/bin/python bench/asklatency.py`"
    if len(sys.argv) > 1:
        command = f"`.venv/bin/python bench/asklatency.py {' '.join(sys.argv[1:])}`"
    rows += [
        "",
        f"{args.rounds} rounds per row (a fresh study with exactly n observations each; the "
        "first round fits cold, later ones warm-start from the previous round). qei: through "
        "HTTP to a real adserver on SQLite, q points in one ask; GPSampler: in-process, "
        "`study.ask()` q times. Goal: q=1, n=50, d=6 under 0.3 s median. "
        f"Run with {command} on 2 shared CPU cores, {elapsed / 60:.1f} min in all.",
    ]
    if not args.no_write:
        write_subsection("### Ask latency (bench/asklatency.py)", "\n".join(rows))


if __name__ == "__main__":
    main()
