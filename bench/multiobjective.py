"""Several objectives (issue 17): hypervolume after 40 and 80 evaluations, qei through the
real service next to Optuna's multi-objective samplers.

Problems (every objective minimised; BoTorch's definitions and reference points):
ZDT1 and ZDT2 on [0, 1]^4 (reference point (11, 11), best hypervolume 120.667 and
120.333) and DTLZ2 with two objectives on [0, 1]^6 (reference (1.1, 1.1), best
0.4246). The hypervolume of a run after k evaluations is that of the non-dominated
ones of its first k evaluations, against the problem's reference point (the studies
are not given it: qei infers its own, as Optuna's samplers do).

Methods, each seeded with the run's seed and asked one point at a time:
- ``qei``, ``random``, ``tpe``: the service's proposers through HTTP, a study of
  ``directions: [minimize, minimize]`` on a real ``adserver`` (SQLite) with
  ``adclient.Client``: ask, evaluate, ``tell(trial, [f1, f2])``; their defaults
  (qei: 2 Sobol points, then qLogNEHVI; tpe: Optuna's multi-objective TPE after 10
  Sobol points).
- ``gp-optuna``, ``nsga2-optuna``, ``tpe-optuna``: Optuna's GPSampler,
  NSGAIISampler and TPESampler (defaults) in a plain Optuna loop, in-process.

The goal (issue 17): qei's median hypervolume at 40 evaluations at or above the best
Optuna sampler's median on each problem. Results are appended to a JSON file
(``--out``, one record per run) as runs finish, so a partial run keeps what it did;
the summary (medians and quartiles at 40 and 80 evaluations, seconds per run) is
printed from that file, and ``--summary-only`` prints it without running (with
``--inputs``, of several files: seeds run side by side with ``--first-seed`` and
``--out`` of their own).

Run: ``.venv/bin/python bench/multiobjective.py`` (10 seeds, all problems and
methods, 80 evaluations; on two shared cores, hours); ``--seeds 3 --evaluations 40``
for a shorter look.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.servers import ServerProcess  # noqa: E402

CHECKPOINTS = (40, 80)
METHODS = ("qei", "random", "tpe", "gp-optuna", "nsga2-optuna", "tpe-optuna")


@dataclass(frozen=True)
class Problem:
    name: str
    dim: int
    ref_point: np.ndarray
    max_hv: float
    evaluate: Callable[[np.ndarray], np.ndarray]
    """Points of [0, 1]^dim (n x dim) -> objectives (n x 2), minimised."""


def _botorch_problem(name: str, dim: int) -> Problem:
    from botorch.test_functions.multi_objective import DTLZ2, ZDT1, ZDT2

    function: Any
    if name == "dtlz2":
        function = DTLZ2(dim=dim, num_objectives=2)
    else:
        function = {"zdt1": ZDT1, "zdt2": ZDT2}[name](dim=dim)

    def evaluate(X: np.ndarray) -> np.ndarray:
        # BoTorch's test functions are written for maximisation of -f: evaluate_true is f
        with torch.no_grad():
            return function.evaluate_true(torch.as_tensor(X, dtype=torch.float64)).numpy()

    return Problem(
        name=name,
        dim=dim,
        ref_point=np.asarray(function._ref_point, dtype=np.float64),
        max_hv=float(function.max_hv),
        evaluate=evaluate,
    )


PROBLEMS = {"zdt1": ("zdt1", 4), "zdt2": ("zdt2", 4), "dtlz2": ("dtlz2", 6)}


def hypervolume(F: np.ndarray, ref_point: np.ndarray) -> float:
    """Hypervolume of minimised objectives F (n x 2) against ``ref_point``."""
    from botorch.utils.multi_objective.hypervolume import Hypervolume
    from botorch.utils.multi_objective.pareto import is_non_dominated

    points = -torch.as_tensor(F, dtype=torch.float64)
    reference = -torch.as_tensor(ref_point, dtype=torch.float64)
    points = points[(points > reference).all(dim=1)]
    if len(points) == 0:
        return 0.0
    return float(Hypervolume(reference).compute(points[is_non_dominated(points)]))


def run_service(url: str, method: str, problem: Problem, seed: int, budget: int) -> np.ndarray:
    """A study of the service's proposer ``method``; the evaluated points in order."""
    from adclient import Client

    client = Client(url, timeout=600)
    study = client.create_study(
        name=f"{problem.name}-{method}-{seed}",
        space={
            "type": "box",
            "params": [{"name": f"x{i}", "low": 0.0, "high": 1.0} for i in range(problem.dim)],
        },
        directions=["minimize", "minimize"],
        proposer={"name": method, "seed": seed},
    )
    points = []
    for _ in range(budget):
        (trial,) = client.ask(study.id)
        x = np.array([[trial.params[f"x{i}"] for i in range(problem.dim)]])
        client.tell(trial, [float(v) for v in problem.evaluate(x)[0]])
        points.append(x[0])
    return np.array(points)


def run_optuna(method: str, problem: Problem, seed: int, budget: int) -> np.ndarray:
    import optuna

    optuna.logging.set_verbosity(optuna.logging.ERROR)
    sampler: Any = {
        "gp-optuna": lambda: optuna.samplers.GPSampler(seed=seed),
        "nsga2-optuna": lambda: optuna.samplers.NSGAIISampler(seed=seed),
        "tpe-optuna": lambda: optuna.samplers.TPESampler(seed=seed),
    }[method]()
    study = optuna.create_study(directions=["minimize", "minimize"], sampler=sampler)
    points = []

    def objective(trial: Any) -> tuple[float, float]:
        x = np.array([[trial.suggest_float(f"x{i}", 0.0, 1.0) for i in range(problem.dim)]])
        points.append(x[0])
        f = problem.evaluate(x)[0]
        return float(f[0]), float(f[1])

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        study.optimize(objective, n_trials=budget)
    return np.array(points)


def summarise(records: list[dict[str, Any]], problems: list[str]) -> list[str]:
    lines = []
    for name in problems:
        mine = [r for r in records if r["problem"] == name]
        if not mine:
            continue
        max_hv = mine[0]["max_hv"]
        lines.append(f"\n{name} (best hypervolume {max_hv:.4g})")
        lines.append(
            "| method | runs | median HV @40 (q1-q3) | median HV @80 (q1-q3) | s per run |"
        )
        lines.append("| --- | --- | --- | --- | --- |")
        for method in METHODS:
            runs = [r for r in mine if r["method"] == method]
            if not runs:
                continue
            cells = []
            for k in CHECKPOINTS:
                values = [r["hv"][str(k)] for r in runs if str(k) in r["hv"]]
                if values:
                    q1, q3 = np.percentile(values, [25, 75])
                    cells.append(f"{statistics.median(values):.4f} ({q1:.4f}-{q3:.4f})")
                else:
                    cells.append("-")
            seconds = statistics.median(r["seconds"] for r in runs)
            lines.append(f"| {method} | {len(runs)} | {cells[0]} | {cells[1]} | {seconds:.0f} |")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--evaluations", type=int, default=80)
    parser.add_argument("--problems", nargs="+", default=list(PROBLEMS), choices=list(PROBLEMS))
    parser.add_argument("--methods", nargs="+", default=list(METHODS), choices=list(METHODS))
    parser.add_argument("--out", type=Path, default=ROOT / "bench/results/multiobjective.json")
    parser.add_argument("--summary-only", action="store_true")
    parser.add_argument(
        "--inputs", nargs="+", type=Path, default=[], help="with --summary-only: more result files"
    )
    args = parser.parse_args()

    args.out.parent.mkdir(parents=True, exist_ok=True)
    records: list[dict[str, Any]] = []
    if args.out.exists():
        records = json.loads(args.out.read_text())
    if args.summary_only:
        for path in args.inputs:
            records += json.loads(path.read_text())
        print("\n".join(summarise(records, args.problems)))
        return
    done = {(r["problem"], r["method"], r["seed"], r["evaluations"]) for r in records}
    with tempfile.TemporaryDirectory() as workdir:
        server = ServerProcess(
            database_url=f"sqlite:///{Path(workdir) / 'mo.db'}", workdir=Path(workdir)
        ).start()
        try:
            for seed in range(args.first_seed, args.first_seed + args.seeds):
                for key in args.problems:
                    problem = _botorch_problem(*PROBLEMS[key])
                    for method in args.methods:
                        if (key, method, seed, args.evaluations) in done:
                            continue
                        started = time.perf_counter()
                        if method.endswith("-optuna"):
                            X = run_optuna(method, problem, seed, args.evaluations)
                        else:
                            X = run_service(server.url, method, problem, seed, args.evaluations)
                        F = problem.evaluate(X)
                        record = {
                            "problem": key,
                            "method": method,
                            "seed": seed,
                            "evaluations": args.evaluations,
                            "max_hv": problem.max_hv,
                            "hv": {
                                str(k): hypervolume(F[:k], problem.ref_point)
                                for k in CHECKPOINTS
                                if k <= len(F)
                            },
                            "seconds": time.perf_counter() - started,
                        }
                        records.append(record)
                        args.out.write_text(json.dumps(records, indent=1))
                        print(
                            f"{key} {method} seed {seed}: "
                            + ", ".join(f"HV@{k} {v:.4f}" for k, v in record["hv"].items())
                            + f" ({record['seconds']:.0f} s)",
                            flush=True,
                        )
        finally:
            server.stop()
    print("\n".join(summarise(records, args.problems)))


if __name__ == "__main__":
    main()
