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

The managed robot problem (``--problems robot``): examples/score-vs-mass.yaml (score
maximised, mass minimised) as a managed study of the service's proposer, evaluated by
``--robot-workers`` real ``adworker`` processes (the example's ``fast`` learner, a search
over joint poses, ``--robot-train-steps`` of it), ``--robot-trials`` evaluations per run;
its hypervolume is against (score 0, mass 14 kg), heavier than any design of the space
(13.8 kg), and no best is known. Only the service's proposers run it (Optuna's samplers
cannot hand jobs to workers).

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
import tempfile
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from adclient.testing.servers import ServerProcess

ROOT = Path(__file__).resolve().parents[1]

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
ROBOT = "robot"
ROBOT_REF = np.array([0.0, 14.0])
"""The robot's reference point, minimised: -score, mass (kg)."""
EXAMPLE = ROOT / "examples" / "score-vs-mass.yaml"


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


def run_robot(
    server: Any, method: str, seed: int, budget: int, workdir: Path, args: argparse.Namespace
) -> np.ndarray:
    """A managed score-vs-mass study of the service's proposer ``method`` evaluated by
    real workers; its trials' minimised objectives (-score, mass) in trial order."""
    import httpx
    import yaml

    from adclient.testing.workers import WorkerProcess

    body = yaml.safe_load(EXAMPLE.read_text(encoding="utf-8"))
    body.update(name=f"robot-{method}-{seed}", max_trials=budget)
    body["proposer"] = {**body["proposer"], "name": method, "seed": seed}
    body["task"]["train_steps"] = args.robot_train_steps
    with httpx.Client(base_url=server.url, timeout=600) as http:
        created = http.post("/api/v1/studies", json=body)
        created.raise_for_status()
        study_id = created.json()["id"]
        workers = [
            WorkerProcess(server, workdir, f"robot-{method}-{seed}-{i}")
            for i in range(args.robot_workers)
        ]
        try:
            while http.get(f"/api/v1/studies/{study_id}").json()["state"] != "complete":
                if all(worker.process.poll() is not None for worker in workers):
                    raise RuntimeError(f"every adworker exited:\n{workers[0].log()[-2000:]}")
                time.sleep(1.0)
        finally:
            for worker in workers:
                worker.stop()
        trials = http.get(f"/api/v1/studies/{study_id}/trials").json()
    rows = [t["values"] for t in sorted(trials, key=lambda t: t["number"]) if t["values"]]
    return np.array([[-score, mass] for score, mass in rows]).reshape(-1, 2)


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
        best = "unknown" if max_hv is None else f"{max_hv:.4g}"
        checkpoints = sorted({int(k) for r in mine for k in r["hv"]})[:3]
        lines.append(f"\n{name} (best hypervolume {best})")
        header = " | ".join(f"median HV @{k} (q1-q3)" for k in checkpoints)
        lines.append(f"| method | runs | {header} | s per run |")
        lines.append("| --- | --- | " + "--- | " * len(checkpoints) + "--- |")
        for method in METHODS:
            runs = [r for r in mine if r["method"] == method]
            if not runs:
                continue
            cells = []
            for k in checkpoints:
                values = [r["hv"][str(k)] for r in runs if str(k) in r["hv"]]
                if values:
                    q1, q3 = np.percentile(values, [25, 75])
                    cells.append(f"{statistics.median(values):.4f} ({q1:.4f}-{q3:.4f})")
                else:
                    cells.append("-")
            seconds = statistics.median(r["seconds"] for r in runs)
            lines.append(f"| {method} | {len(runs)} | {' | '.join(cells)} | {seconds:.0f} |")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--evaluations", type=int, default=80)
    parser.add_argument(
        "--problems", nargs="+", default=[*PROBLEMS, ROBOT], choices=[*PROBLEMS, ROBOT]
    )
    parser.add_argument("--robot-trials", type=int, default=40)
    parser.add_argument("--robot-train-steps", type=int, default=1024)
    parser.add_argument("--robot-workers", type=int, default=2)
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
                    robot = key == ROBOT
                    budget = args.robot_trials if robot else args.evaluations
                    for method in args.methods:
                        if (key, method, seed, budget) in done or (robot and "optuna" in method):
                            continue
                        started = time.perf_counter()
                        if robot:
                            F, ref, max_hv = (
                                run_robot(server, method, seed, budget, Path(workdir), args),
                                ROBOT_REF,
                                None,
                            )
                        else:
                            problem = _botorch_problem(*PROBLEMS[key])
                            if method.endswith("-optuna"):
                                X = run_optuna(method, problem, seed, budget)
                            else:
                                X = run_service(server.url, method, problem, seed, budget)
                            F, ref, max_hv = problem.evaluate(X), problem.ref_point, problem.max_hv
                        record = {
                            "problem": key,
                            "method": method,
                            "seed": seed,
                            "evaluations": budget,
                            "max_hv": max_hv,
                            "hv": {
                                str(k): hypervolume(F[:k], ref)
                                for k in sorted({*CHECKPOINTS, len(F)})
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
