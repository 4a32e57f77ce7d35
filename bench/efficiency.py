"""Sample efficiency: evaluations to come within 1% of the optimum, qei against its peers.

Functions (both minimised): Branin on [-5, 10] x [0, 15] (f* = 0.397887) and
Hartmann6 on [0, 1]^6 (f* = -3.32237). *Within 1%* means best-so-far minus f* at or
below 1% of |f*|: 0.00398 for Branin, 0.0332 for Hartmann6 (Hartmann6's second-best
local minimum, -3.2032, is outside it).

Methods, all seeded with the run's seed:
- ``qei``, ``tpe``, ``nelder-mead``, ``random``: the service's proposers called
  in-process (no HTTP), asking one point at a time with their defaults
  (qei: 2 Sobol points, then qLogEI; tpe: Optuna's TPE, multivariate, after 10
  Sobol points; nelder-mead: SciPy's, replayed).
- ``gp-optuna``: Optuna's own GPSampler in a plain Optuna loop, defaults except
  ``deterministic_objective=True`` (the functions are noise-free, as qei is told):
  10 random start-up trials.
- ``gp-optuna-qei-start``: the same GPSampler, but started from qei's own two Sobol
  points (enqueued, ``n_startup_trials=2``): the two GP methods from one start, so
  the start's share of the difference shows.

A run stops once it reaches the target (best-so-far cannot get worse, so the curve
is carried flat to the budget in the plot); unreached runs count as "more than the
budget" and the median is ">budget" when more than half are unreached.

Run: ``.venv/bin/python bench/efficiency.py`` (10 seeds, both functions, all methods,
writes bench/RESULTS.md and docs/efficiency_*.png); ``--seeds 3 --no-write`` while
developing.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "service"))
sys.path.insert(0, str(ROOT))

from adservice.proposers import get_proposer  # noqa: E402
from adservice.proposers.base import ProposalRequest, empty_history  # noqa: E402
from adservice.proposers.simple import sobol_points  # noqa: E402
from bench.proposer_results import write_subsection  # noqa: E402


def branin(x: np.ndarray) -> float:
    x1, x2 = float(x[0]), float(x[1])
    b, c, r, s, t = 5.1 / (4 * math.pi**2), 5 / math.pi, 6.0, 10.0, 1 / (8 * math.pi)
    return (x2 - b * x1**2 + c * x1 - r) ** 2 + s * (1 - t) * math.cos(x1) + s


_H_ALPHA = np.array([1.0, 1.2, 3.0, 3.2])
_H_A = np.array(
    [
        [10, 3, 17, 3.5, 1.7, 8],
        [0.05, 10, 17, 0.1, 8, 14],
        [3, 3.5, 1.7, 10, 17, 8],
        [17, 8, 0.05, 10, 0.1, 14],
    ]
)
_H_P = 1e-4 * np.array(
    [
        [1312, 1696, 5569, 124, 8283, 5886],
        [2329, 4135, 8307, 3736, 1004, 9991],
        [2348, 1451, 3522, 2883, 3047, 6650],
        [4047, 8828, 8732, 5743, 1091, 381],
    ]
)


def hartmann6(x: np.ndarray) -> float:
    inner = np.sum(_H_A * (np.asarray(x)[None, :] - _H_P) ** 2, axis=1)
    return float(-np.sum(_H_ALPHA * np.exp(-inner)))


@dataclass(frozen=True)
class Problem:
    name: str
    function: Callable[[np.ndarray], float]
    bounds: np.ndarray
    optimum: float
    budget: int

    @property
    def tolerance(self) -> float:
        return 0.01 * abs(self.optimum)


PROBLEMS = {
    "branin": Problem("Branin", branin, np.array([[-5.0, 0.0], [10.0, 15.0]]), 0.397887, 60),
    "hartmann6": Problem("Hartmann6", hartmann6, np.array([[0.0] * 6, [1.0] * 6]), -3.32237, 120),
}
METHODS = ["qei", "gp-optuna", "gp-optuna-qei-start", "tpe", "nelder-mead", "random"]


@dataclass
class Run:
    values: list[float] = field(default_factory=list)
    ask_seconds: list[float] = field(default_factory=list)

    def best_gaps(self, problem: Problem) -> np.ndarray:
        best = np.minimum.accumulate(np.array(self.values))
        return best - problem.optimum

    def evaluations_to_target(self, problem: Problem) -> int | None:
        reached = np.flatnonzero(self.best_gaps(problem) <= problem.tolerance)
        return int(reached[0]) + 1 if len(reached) else None


def run_proposer(name: str, problem: Problem, seed: int) -> Run:
    proposer = get_proposer(name)
    dim = problem.bounds.shape[1]
    X, y = empty_history(dim), np.zeros(0)
    run = Run()
    for n in range(problem.budget):
        request = ProposalRequest(
            bounds=problem.bounds,
            count=1,
            seed=seed,
            n_issued=n,
            X=X,
            y=y,
            failed=empty_history(dim),
            pending=empty_history(dim),
        )
        started = time.perf_counter()
        (x,) = proposer.propose(request).candidates
        run.ask_seconds.append(time.perf_counter() - started)
        value = problem.function(x)
        run.values.append(value)
        X = np.vstack([X, x])
        y = np.append(y, -value)  # the service orients y so that larger is better
        if value - problem.optimum <= problem.tolerance:
            break
    return run


def run_gp_optuna(problem: Problem, seed: int, *, qei_start: bool = False) -> Run:
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    dim = problem.bounds.shape[1]
    distributions = {
        f"x{i}": optuna.distributions.FloatDistribution(
            float(problem.bounds[0, i]), float(problem.bounds[1, i])
        )
        for i in range(dim)
    }
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        n_startup = 2 if qei_start else 10
        sampler = optuna.samplers.GPSampler(
            seed=seed, deterministic_objective=True, n_startup_trials=n_startup
        )
        study = optuna.create_study(direction="minimize", sampler=sampler)
        if qei_start:
            low, high = problem.bounds
            for unit in sobol_points(dim, seed, 0, n_startup):
                vector = low + unit * (high - low)
                study.enqueue_trial({f"x{i}": float(vector[i]) for i in range(dim)})
        run = Run()
        for _ in range(problem.budget):
            started = time.perf_counter()
            trial = study.ask(distributions)
            run.ask_seconds.append(time.perf_counter() - started)
            x = np.array([trial.params[f"x{i}"] for i in range(dim)])
            value = problem.function(x)
            study.tell(trial, value)
            run.values.append(value)
            if value - problem.optimum <= problem.tolerance:
                break
    return run


def run_method(method: str, problem: Problem, seed: int) -> Run:
    if method.startswith("gp-optuna"):
        return run_gp_optuna(problem, seed, qei_start=method == "gp-optuna-qei-start")
    return run_proposer(method, problem, seed)


def summarise(problem: Problem, runs: dict[str, list[Run]]) -> list[str]:
    rows = [
        f"**{problem.name}** (d = {problem.bounds.shape[1]}, budget {problem.budget} "
        f"evaluations, target: best - f* <= {problem.tolerance:.4g} = 1% of |f*|)",
        "",
        "| method | reached | median evals | quartiles | per-seed evals | median ask (s) |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for method, method_runs in runs.items():
        counts = [run.evaluations_to_target(problem) for run in method_runs]
        as_numbers = np.array([c if c is not None else np.inf for c in counts], dtype=float)
        reached = sum(c is not None for c in counts)

        def show(value: float) -> str:
            return f">{problem.budget}" if not np.isfinite(value) else f"{value:g}"

        median = show(float(np.median(as_numbers)))
        low, high = (
            np.percentile(as_numbers, [25, 75], method="lower"),
            np.percentile(as_numbers, [75], method="higher")[0],
        )
        quartiles = f"{show(float(low[0]))}-{show(float(high))}"
        per_seed = " ".join("-" if c is None else str(c) for c in counts)
        asks = np.concatenate([run.ask_seconds for run in method_runs])
        rows.append(
            f"| {method} | {reached}/{len(counts)} | {median} | {quartiles} | {per_seed} | "
            f"{np.median(asks):.3f} |"
        )
    return rows


def plot(problem: Problem, runs: dict[str, list[Run]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axis = plt.subplots(figsize=(7, 4.5))
    steps = np.arange(1, problem.budget + 1)
    for method, method_runs in runs.items():
        curves = []
        for run in method_runs:
            gaps = run.best_gaps(problem)
            curves.append(np.concatenate([gaps, np.full(problem.budget - len(gaps), gaps[-1])]))
        gap = np.maximum(np.array(curves), 1e-6)
        median = np.median(gap, axis=0)
        low, high = np.percentile(gap, 25, axis=0), np.percentile(gap, 75, axis=0)
        (line,) = axis.plot(steps, median, label=method)
        axis.fill_between(steps, low, high, color=line.get_color(), alpha=0.15)
    axis.axhline(problem.tolerance, color="black", linestyle="--", linewidth=1, label="1% target")
    axis.set_yscale("log")
    axis.set_xlabel("evaluations")
    axis.set_ylabel("best-so-far minus optimum")
    axis.set_title(
        f"{problem.name}: median and quartiles over {len(next(iter(runs.values())))} seeds"
        " (runs stop at the target)"
    )
    axis.legend()
    figure.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=110)
    plt.close(figure)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--functions", nargs="+", default=list(PROBLEMS), choices=list(PROBLEMS))
    parser.add_argument("--methods", nargs="+", default=METHODS, choices=METHODS)
    parser.add_argument("--no-write", action="store_true", help="print only")
    args = parser.parse_args()

    started = time.perf_counter()
    report: list[str] = []
    for key in args.functions:
        problem = PROBLEMS[key]
        runs: dict[str, list[Run]] = {}
        for method in args.methods:
            runs[method] = []
            for seed in range(args.first_seed, args.first_seed + args.seeds):
                run = run_method(method, problem, seed)
                runs[method].append(run)
                print(
                    f"{problem.name} {method} seed {seed}: "
                    f"{run.evaluations_to_target(problem) or '-'} evals, "
                    f"{sum(run.ask_seconds):.1f} s asking",
                    flush=True,
                )
        rows = summarise(problem, runs)
        print("\n".join(rows), flush=True)
        report += [*rows, ""]
        if not args.no_write:
            plot(problem, runs, ROOT / "docs" / f"efficiency_{key}.png")
            report.append(f"![{problem.name}](../docs/efficiency_{key}.png)")
            report.append("")
    elapsed = time.perf_counter() - started
    command = "`.venv/bin/python bench/efficiency.py`"
    if len(sys.argv) > 1:
        command = f"`.venv/bin/python bench/efficiency.py {' '.join(sys.argv[1:])}`"
    report.append(
        f"{args.seeds} seeds ({args.first_seed}-{args.first_seed + args.seeds - 1}); "
        f"run with {command} on 2 shared CPU cores, "
        f"{elapsed / 60:.1f} min in all. Ask times are in-process (no HTTP)."
    )
    if not args.no_write:
        write_subsection("### Efficiency (bench/efficiency.py)", "\n".join(report))


if __name__ == "__main__":
    main()
