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

Mixed-type params (issue 16), ``--mixed``: two objectives over ints, a log-scaled
float and a categorical (``MIXED``), 40 evaluations each, qei (the service's encoding
and snapping, ``adclient.boxspace``) side by side with Optuna's GPSampler and
TPESampler given the same params as Optuna distributions, and random, same seeds;
the score is the median best value after 40 evaluations (section "Mixed-type params
(issue 16)" of bench/RESULTS.md).
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
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "service"))
sys.path.insert(0, str(ROOT))

from adclient.boxspace import BoxEncoding  # noqa: E402
from adservice.proposers import get_proposer  # noqa: E402
from adservice.proposers.base import ProposalRequest, empty_history  # noqa: E402
from adservice.proposers.simple import sobol_points  # noqa: E402
from bench.proposer_results import write_section, write_subsection  # noqa: E402


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


def ask_loop(
    name: str,
    *,
    bounds: np.ndarray,
    seed: int,
    budget: int,
    evaluate: Callable[[np.ndarray], float],
    box: BoxEncoding | None = None,
    done: Callable[[float], bool] = lambda value: False,
) -> Run:
    """The service's proposer asked one point at a time in-process; a typed box's
    proposals snapped as the service stores them."""
    proposer = get_proposer(name)
    dim = bounds.shape[1]
    X, y = empty_history(dim), np.zeros(0)
    run = Run()
    for n in range(budget):
        request = ProposalRequest(
            bounds=bounds,
            count=1,
            seed=seed,
            n_issued=n,
            X=X,
            y=y,
            failed=empty_history(dim),
            pending=empty_history(dim),
            box=box,
        )
        started = time.perf_counter()
        candidates = proposer.propose(request).candidates
        x = candidates[0] if box is None else box.snap(candidates)[0]
        run.ask_seconds.append(time.perf_counter() - started)
        value = evaluate(x)
        run.values.append(value)
        X = np.vstack([X, x])
        y = np.append(y, -value)  # the service orients y so that larger is better
        if done(value):
            break
    return run


def run_proposer(name: str, problem: Problem, seed: int) -> Run:
    return ask_loop(
        name,
        bounds=problem.bounds,
        seed=seed,
        budget=problem.budget,
        evaluate=problem.function,
        done=lambda value: value - problem.optimum <= problem.tolerance,
    )


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


def hyperparameters(p: dict[str, Any]) -> float:
    """A learner's loss over its hyperparameters, smooth: each activation has its own best
    learning rate (10^-3.2 for gelu, 10^-1.5 for sigmoid) and floor (gelu 0, relu 0.3),
    the rate spans five decades (only a log scale searches it evenly), the width two
    octaves either side of 64. f* = 0 (gelu, lr 10^-3.2, width 64, 3 layers, dropout 0.25)."""
    best_lr, floor = _ACTIVATIONS[p["activation"]]
    depth = p["layers"] - 3
    octaves = math.log2(p["width"]) - 6
    return (
        floor
        + 0.5 * (math.log10(p["lr"]) - best_lr) ** 2
        + 0.15 * octaves**2
        + 0.2 * depth**2
        + 0.1 * depth * octaves
        + 2.0 * (p["dropout"] - 0.25) ** 2
    )


_ACTIVATIONS = {
    "relu": (-3.0, 0.3),
    "tanh": (-2.0, 0.6),
    "sigmoid": (-1.5, 1.0),
    "gelu": (-3.2, 0.0),
}


def rugged(p: dict[str, Any]) -> float:
    """Interactions and ripples: the kind picks where the two ints are best and the
    scale's decade; x must follow half the scale's decade (a curved valley through a
    log scale), and n1 ripples (period 4). f* = 0 (kind c, n1 11, n2 3, scale 10^0.5, x
    0.25)."""
    a, b, u, offset = _KINDS[p["kind"]]
    decade = math.log10(p["scale"])
    return (
        offset
        + ((p["n1"] - a) / 4) ** 2
        + ((p["n2"] - b) / 4) ** 2
        + 0.3 * (1 - math.cos(math.pi * (p["n1"] - a) / 2))
        + (p["x"] - 0.5 * decade) ** 2
        + 0.3 * (decade - u) ** 2
    )


_KINDS = {
    "a": (3, 12, -2.0, 0.5),
    "b": (8, 8, 2.0, 0.25),
    "c": (11, 3, 0.5, 0.0),
    "d": (1, 1, -1.0, 0.4),
    "e": (14, 14, 2.5, 0.6),
}


@dataclass(frozen=True)
class MixedProblem:
    name: str
    function: Callable[[dict[str, Any]], float]
    space: dict[str, Any]
    budget: int = 40

    @property
    def box(self) -> BoxEncoding:
        return BoxEncoding.of(self.space)


MIXED = {
    "hyperparameters": MixedProblem(
        "Hyperparameters",
        hyperparameters,
        {
            "type": "box",
            "params": [
                {"name": "lr", "low": 1e-5, "high": 1.0, "log": True},
                {"name": "width", "type": "int", "low": 4, "high": 1024, "log": True},
                {"name": "layers", "type": "int", "low": 1, "high": 8},
                {"name": "dropout", "low": 0.0, "high": 0.8},
                {"name": "activation", "type": "categorical", "choices": list(_ACTIVATIONS)},
            ],
        },
    ),
    "rugged": MixedProblem(
        "Rugged",
        rugged,
        {
            "type": "box",
            "params": [
                {"name": "n1", "type": "int", "low": 0, "high": 15},
                {"name": "n2", "type": "int", "low": 0, "high": 15},
                {"name": "scale", "low": 1e-3, "high": 1e3, "log": True},
                {"name": "x", "low": -3.0, "high": 3.0},
                {"name": "kind", "type": "categorical", "choices": list(_KINDS)},
            ],
        },
    ),
}
MIXED_METHODS = ["qei", "gp-optuna", "tpe-optuna", "random"]


def run_mixed_proposer(name: str, problem: MixedProblem, seed: int) -> Run:
    box = problem.box
    return ask_loop(
        name,
        bounds=box.bounds,
        seed=seed,
        budget=problem.budget,
        evaluate=lambda x: problem.function(box.decode(x)),
        box=box,
    )


def run_mixed_optuna(sampler_name: str, problem: MixedProblem, seed: int) -> Run:
    """Optuna's own sampler over the same params as its distributions (defaults;
    GPSampler told the objective is deterministic, as qei is)."""
    import optuna
    from optuna.distributions import CategoricalDistribution, FloatDistribution, IntDistribution

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    distributions: dict[str, Any] = {}
    for p in problem.box.params:
        if p.type == "categorical":
            distributions[p.name] = CategoricalDistribution(p.choices or [])
        elif p.type == "int":
            distributions[p.name] = IntDistribution(int(p.low or 0), int(p.high or 0), log=p.log)
        else:
            distributions[p.name] = FloatDistribution(
                float(p.low or 0), float(p.high or 0), log=p.log
            )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sampler: optuna.samplers.BaseSampler
        if sampler_name == "gp-optuna":
            sampler = optuna.samplers.GPSampler(seed=seed, deterministic_objective=True)
        else:
            sampler = optuna.samplers.TPESampler(seed=seed)
        study = optuna.create_study(direction="minimize", sampler=sampler)
        run = Run()
        for _ in range(problem.budget):
            started = time.perf_counter()
            trial = study.ask(distributions)
            run.ask_seconds.append(time.perf_counter() - started)
            value = problem.function(trial.params)
            study.tell(trial, value)
            run.values.append(value)
    return run


def summarise_mixed(problem: MixedProblem, runs: dict[str, list[Run]]) -> tuple[list[str], bool]:
    """The table of best values after the budget (lower is better) and whether qei's
    median is at or below both Optuna samplers'."""
    rows = [
        f"**{problem.name}** ({len(problem.space['params'])} params: "
        + ", ".join(
            f"{p['name']} {p.get('type', 'float')}{' log' if p.get('log') else ''}"
            for p in problem.space["params"]
        )
        + f"; minimised, f* = 0; best after {problem.budget} evaluations)",
        "",
        "| method | median best | quartiles | per-seed best | median ask (s) |",
        "| --- | --- | --- | --- | --- |",
    ]
    medians = {}
    for method, method_runs in runs.items():
        best = np.array([min(run.values[: problem.budget]) for run in method_runs])
        medians[method] = float(np.median(best))
        low, high = np.percentile(best, [25, 75])
        asks = np.concatenate([run.ask_seconds for run in method_runs])
        rows.append(
            f"| {method} | {medians[method]:.4f} | {low:.4f}-{high:.4f} | "
            f"{' '.join(f'{b:.3f}' for b in best)} | {np.median(asks):.3f} |"
        )
    met = all(medians["qei"] <= medians[other] for other in ("gp-optuna", "tpe-optuna"))
    return rows, met


def run_mixed(key: str, method: str, seed: int) -> Run:
    problem = MIXED[key]
    if method.endswith("-optuna"):
        return run_mixed_optuna(method, problem, seed)
    return run_mixed_proposer(method, problem, seed)


def main_mixed(args: argparse.Namespace) -> None:
    """Every (objective, method, seed) run, ``--jobs`` at a time in processes of their own."""
    from concurrent.futures import ProcessPoolExecutor

    started = time.perf_counter()
    report: list[str] = []
    verdicts = []
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    tasks = [(key, method, seed) for key in MIXED for method in MIXED_METHODS for seed in seeds]
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        futures = {task: pool.submit(run_mixed, *task) for task in tasks}
        for (key, method, seed), future in futures.items():
            run = future.result()
            print(
                f"{MIXED[key].name} {method} seed {seed}: best {min(run.values):.4f}, "
                f"{sum(run.ask_seconds):.1f} s asking",
                flush=True,
            )
    for key, problem in MIXED.items():
        runs = {
            method: [futures[(key, method, seed)].result() for seed in seeds]
            for method in MIXED_METHODS
        }
        rows, met = summarise_mixed(problem, runs)
        verdicts.append(f"{problem.name}: {'met' if met else 'missed'}")
        print("\n".join(rows), flush=True)
        report += [*rows, ""]
    elapsed = time.perf_counter() - started
    report.append(
        "Goal: qei's median best after 40 evaluations at or below (better than or equal "
        f"to) both GPSampler's and TPESampler's. {'; '.join(verdicts)}."
    )
    report.append("")
    report.append(
        f"{args.seeds} seeds ({args.first_seed}-{args.first_seed + args.seeds - 1}), each "
        "method the same seeds, runs side by side (ask times are under that load); run with "
        f"`nice -n 10 .venv/bin/python bench/efficiency.py {' '.join(sys.argv[1:])}` on 2 "
        f"shared CPU cores, {elapsed / 60:.1f} min in all. Ask times are in-process."
    )
    if not args.no_write:
        write_section("## Mixed-type params (issue 16)", "\n".join(report))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--functions", nargs="+", default=list(PROBLEMS), choices=list(PROBLEMS))
    parser.add_argument("--methods", nargs="+", default=METHODS, choices=METHODS)
    parser.add_argument("--no-write", action="store_true", help="print only")
    parser.add_argument(
        "--mixed", action="store_true", help="the mixed-type objectives (issue 16) instead"
    )
    parser.add_argument("--jobs", type=int, default=1, help="--mixed: runs at once")
    args = parser.parse_args()
    if args.mixed:
        main_mixed(args)
        return

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
