"""Asks of studies with thousands of observations (issue 37): qei's model-based ask past
``max_train`` observations (a subset: ``adservice.proposers.subset``) against the full
exact GP, side by side in one run.

For each test function (Hartmann6, and Ackley in 8 dimensions: their negatives
maximised, through BoTorch's test functions) and each seed, a history of n uniformly
random points (the study a cheap simulator or a function worker makes) is given to
``QLogEIProposer`` in process (no memory budget in the way: the full arm must run), and
``--asks`` asks of q = 1 follow, each told its true value. The arms:

- ``subset``: the default (``max_train`` 1024);
- ``full``: ``max_train = n`` (every observation, as before issue 37, with the memory
  budget it needs: an exact GP of n = 3,000 needs about 1.7 GB by the estimate);
- ``random``: uniform points, what a fall back to Sobol points gave.

Reported per (function, n, arm): how many asks were the model's, the wall seconds per
ask, and the fraction of the gap between the history's best and the optimum that the
asks closed (0: none; 1: all), median and lower quartile over the seeds. Peak memory
of one ask is measured in a fresh process per (n, arm) (``--memory``).

Run: ``.venv/bin/python bench/large_history.py`` (``--n 2000 10000 --seeds 10``).
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from typing import Any

import numpy as np
import torch
from botorch.test_functions import Ackley, Hartmann

from adservice.proposers.base import ProposalRequest, empty_history
from adservice.proposers.qei import QLogEIProposer

BUDGET = 64 * 2**30
"""No budget in the way: the full arm must run to be compared (the default is 1024 MB)."""
FUNCTIONS = {"hartmann6": (Hartmann(dim=6), 6), "ackley8": (Ackley(dim=8), 8)}


def scaled(name: str, unit: np.ndarray) -> np.ndarray:
    """The function's value (to maximise) at points of the unit box."""
    function, _ = FUNCTIONS[name]
    bounds = function.bounds.numpy()
    x = bounds[0] + unit * (bounds[1] - bounds[0])
    with torch.no_grad():
        return -function.evaluate_true(torch.as_tensor(x)).numpy()


def optimum(name: str) -> float:
    function, _ = FUNCTIONS[name]
    return -float(function.optimal_value)


def history(name: str, n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    dim = FUNCTIONS[name][1]
    unit = np.random.default_rng([seed, n, dim]).random((n, dim))
    return unit, scaled(name, unit)


def run(name: str, n: int, seed: int, arm: str, asks: int) -> dict[str, Any]:
    """``asks`` asks of q = 1 after the history, each told its true value; ``arm``:
    ``subset`` (the default), ``full`` (max_train = n) or ``random`` (uniform points:
    what a fall back to Sobol points gave)."""
    X, y = history(name, n, seed)
    dim = X.shape[1]
    best_before = float(y.max())
    methods, seconds = [], []
    rng = np.random.default_rng([seed, n, 7])
    for k in range(asks):
        started = time.perf_counter()
        if arm == "random":
            candidate = rng.random((1, dim))
            methods.append("random")
        else:
            request = ProposalRequest(
                bounds=np.array([[0.0] * dim, [1.0] * dim]),
                count=1,
                seed=seed,
                n_issued=n + k,
                X=X,
                y=y,
                failed=empty_history(dim),
                pending=empty_history(dim),
                options={"max_train": n + k} if arm == "full" else {},
                memory_bytes=BUDGET,
            )
            proposal = QLogEIProposer().propose(request)
            candidate = proposal.candidates
            methods.append(proposal.info[0]["method"])
        seconds.append(time.perf_counter() - started)
        X = np.vstack([X, candidate])
        y = np.append(y, scaled(name, candidate))
    gap = optimum(name) - best_before
    return {
        "methods": methods,
        "seconds": seconds,
        "closed": (float(y.max()) - best_before) / gap,
    }


def resident_mb() -> float:
    with open("/proc/self/statm") as statm:
        return int(statm.read().split()[1]) * resource.getpagesize() / 2**20


def peak_memory(name: str, n: int, arm: str) -> float:
    """MB one ask adds to a fresh process's resident memory at its peak."""
    code = (
        "import resource, json; from bench.large_history import run, history, resident_mb;"
        f"run({name!r}, 50, 0, {arm!r}, 1); history({name!r}, {n}, 0); before = resident_mb();"
        f"run({name!r}, {n}, 0, {arm!r}, 1);"
        "print(json.dumps(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024 - before))"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return float(json.loads(done.stdout.strip().splitlines()[-1]))


def quartiles(values: list[float]) -> str:
    return f"{np.median(values):.3f} / {np.percentile(values, 25):.3f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--n", type=int, nargs="+", default=[2000, 10000])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--asks", type=int, default=5)
    parser.add_argument("--functions", nargs="+", default=list(FUNCTIONS))
    parser.add_argument("--full-up-to", type=int, default=3000, help="skip the full arm past it")
    parser.add_argument("--memory", action="store_true", help="peak memory per (n, arm)")
    args = parser.parse_args()
    memory = " peak MB of an ask |" if args.memory else ""
    print(
        f"| function | n | arm | model asks | seconds per ask: median / max "
        f"| gap closed: median / lower quartile |{memory}"
    )
    print("| --- | --- | --- | --- | --- | --- |" + (" --- |" if args.memory else ""))
    for name in args.functions:
        for n in args.n:
            arms = ["subset"] + (["full"] if n <= args.full_up_to else []) + ["random"]
            for arm in arms:
                runs = [run(name, n, seed, arm, args.asks) for seed in range(args.seeds)]
                methods = [m for r in runs for m in r["methods"]]
                model = sum(not m.startswith(("sobol", "random")) for m in methods)
                seconds = [t for r in runs for t in r["seconds"]]
                closed = [r["closed"] for r in runs]
                row = (
                    f"| {name} | {n} | {arm} | {model} of {len(methods)} "
                    f"| {np.median(seconds):.2f} / {max(seconds):.2f} "
                    f"| {np.median(closed):.3f} / {np.percentile(closed, 25):.3f} |"
                )
                if args.memory and arm != "random":
                    row += f" {peak_memory(name, n, arm):.0f} |"
                elif args.memory:
                    row += " |"
                print(row, flush=True)


if __name__ == "__main__":
    main()
