"""Ask latency of ``qei`` with two objectives, in-process (no HTTP), side by side with
Optuna's GPSampler on the same histories.

Issue 17's goal: an ask of q = 1 at n = 80 observations of m = 2 objectives under
1 s. Histories of n points, minimised objectives, where a late study stands:
half uniform in the box and half within 5% of the problem's Pareto set (so the
observed front is tens of points, as it is after a study has found the front; a
uniform history alone has a front of a few points and flatters the Monte Carlo
acquisition, whose cost grows with the front). Problems: ZDT1 (d = 4) and DTLZ2
(d = 6), BoTorch's definitions.

Methods, each asked ``--rounds`` times per problem, the first n - 1 points the same
every round and the last one different, so from the second round on each GP
warm-starts from the previous fit as a running study's next ask does (the first
round fits cold and is part of the figures):

- ``qei``: the default, analytic LogEHVI with Kriging believers;
- ``qei-mc``: ``options: {acquisition: mc}``, BoTorch's qLogNEHVI;
- ``gp-optuna``: Optuna's GPSampler, ``study.ask()`` on a study holding the same
  trials (its relative sampling fits its GPs and maximises its LogEHVI).

Printed per problem and method: the front's size, the median and the worst of the
process's CPU time per ask (every thread's, so a sampler's own threads count) and
the median wall time, and the median CPU time as a ratio to the 1 s bound and to
GPSampler's. qei's ask runs with one torch thread, so on an idle machine its wall
time is its CPU time; on a shared one the wall time also counts the waits for a
core.

Run: ``.venv/bin/python bench/mo_asklatency.py`` (a few minutes; ``--methods qei``
for the default alone; ``--constraints 1`` adds a constraint x0 >= 0.5 to qei's
studies, one more GP).
"""

from __future__ import annotations

import argparse
import statistics
import time
import warnings
from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from adservice.proposers import get_proposer
from adservice.proposers.base import ProposalRequest, empty_history
from adservice.proposers.gpfit import clear_caches

METHODS = ("qei", "qei-mc", "gp-optuna")
BOUND_SECONDS = 1.0


def problem(name: str) -> tuple[int, Callable[[np.ndarray], np.ndarray], Callable[..., Any]]:
    """(d, minimised objectives of n x d points, a sampler of points near the Pareto set)."""
    from botorch.test_functions.multi_objective import DTLZ2, ZDT1

    d = {"zdt1": 4, "dtlz2": 6}[name]
    function = ZDT1(dim=d) if name == "zdt1" else DTLZ2(dim=d, num_objectives=2)

    def evaluate(X: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return function.evaluate_true(torch.as_tensor(X, dtype=torch.float64)).numpy()

    def near_front(rng: np.random.Generator, n: int) -> np.ndarray:
        X = rng.random((n, d))
        centre = 0.0 if name == "zdt1" else 0.5  # the Pareto set: x1..x(d-1) at this value
        X[:, 1:] = centre + 0.05 * (rng.random((n, d - 1)) - (0.0 if name == "zdt1" else 0.5))
        return X

    return d, evaluate, near_front


def history(name: str, n: int, rng: np.random.Generator) -> np.ndarray:
    d, _, near_front = problem(name)
    return np.vstack([rng.random((n - n // 2, d)), near_front(rng, n // 2)])


def ask_qei(X: np.ndarray, F: np.ndarray, q: int, constraints: int, options: dict) -> dict:
    d = X.shape[1]
    request = ProposalRequest(
        bounds=np.array([np.zeros(d), np.ones(d)]),
        count=q,
        seed=1,
        n_issued=len(X),
        X=X,
        y=-F[:, 0],
        failed=empty_history(d),
        pending=empty_history(d),
        n_initial=10,
        objectives=-F,
        slacks=(0.5 - X[:, :1]) if constraints else None,
        options=options,
    )
    info = get_proposer("qei").propose(request).info[0]
    assert info["method"] in ("LogEHVI", "qLogNEHVI"), info
    return info


def ask_optuna(X: np.ndarray, F: np.ndarray) -> dict:
    import optuna

    optuna.logging.set_verbosity(optuna.logging.ERROR)
    d = X.shape[1]
    distributions = {f"x{i}": optuna.distributions.FloatDistribution(0.0, 1.0) for i in range(d)}
    study = optuna.create_study(
        directions=["minimize", "minimize"], sampler=optuna.samplers.GPSampler(seed=1)
    )
    study.add_trials(
        [
            optuna.trial.create_trial(
                params={f"x{i}": float(x[i]) for i in range(d)},
                distributions=distributions,
                values=[float(v) for v in f],
            )
            for x, f in zip(X, F, strict=True)
        ]
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        study.ask(distributions)
    return {}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--n", type=int, default=80)
    parser.add_argument("--q", type=int, default=1)
    parser.add_argument("--rounds", type=int, default=10)
    parser.add_argument("--problems", nargs="+", default=["zdt1", "dtlz2"])
    parser.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS)
    parser.add_argument("--constraints", type=int, choices=[0, 1], default=0)
    args = parser.parse_args()

    lines = [
        "| problem | front | method | CPU s per ask, median (max) | wall s, median "
        "| CPU / 1 s bound | CPU / GPSampler |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for name in args.problems:
        d, evaluate, _ = problem(name)
        rng = np.random.default_rng(0)
        fixed = history(name, args.n - 1, rng)
        lasts = rng.random((args.rounds, d))
        front = None
        medians: dict[str, float] = {}
        rows = []
        for method in args.methods:
            clear_caches()
            cpus, walls = [], []
            for last in lasts:
                X = np.vstack([fixed, last[None, :]])
                F = evaluate(X)
                wall, cpu = time.perf_counter(), time.process_time()
                if method == "gp-optuna":
                    info = ask_optuna(X, F)
                else:
                    options = {"acquisition": "mc"} if method == "qei-mc" else {}
                    info = ask_qei(X, F, args.q, args.constraints, options)
                cpus.append(time.process_time() - cpu)
                walls.append(time.perf_counter() - wall)
                front = info.get("n_pareto", front)
            medians[method] = statistics.median(cpus)
            print(f"{name} {method}: cpu {[round(c, 3) for c in cpus]}", flush=True)
            rows.append((method, cpus, walls))
        for method, cpus, walls in rows:
            peer = medians.get("gp-optuna")
            lines.append(
                f"| {name} (d={d}) | {front} | {method} | {medians[method]:.3f} ({max(cpus):.3f}) "
                f"| {statistics.median(walls):.3f} | {medians[method] / BOUND_SECONDS:.2f} "
                f"| {medians[method] / peer:.2f} |"
                if peer
                else f"| {name} (d={d}) | {front} | {method} | {medians[method]:.3f} "
                f"({max(cpus):.3f}) | {statistics.median(walls):.3f} "
                f"| {medians[method] / BOUND_SECONDS:.2f} | - |"
            )
    print(
        f"\nn={args.n}, m=2, q={args.q}, constraints={args.constraints}, "
        f"{args.rounds} rounds per method"
    )
    print("\n".join(lines))


if __name__ == "__main__":
    main()
