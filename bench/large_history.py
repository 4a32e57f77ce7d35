"""Asks of studies with thousands of observations (issue 37): qei's model-based ask past
``max_train`` observations (a subset: ``adservice.proposers.subset``) against the full
exact GP, side by side in one run.

For each test function (Hartmann6 and Ackley in 8 dimensions, both maximised as their
negatives are minimised, through BoTorch's test functions) and each seed, a history of
n uniformly random points (the study a cheap simulator or a function worker makes) is
given to ``QLogEIProposer`` in process with the server's default memory budget
(1024 MB). One ask of q = 1 is made by each arm:

- ``subset``: the default (``max_train`` 1024);
- ``full``: ``max_train = n`` (every observation, as before issue 37).

Reported per (function, n, arm): how the ask was made (model or a Sobol fall back),
its wall seconds, and the true value of its candidate as a fraction of the way from the
history's best to the function's optimum (0: no better than the best observed; 1: the
optimum; negative: worse), median and lower quartile over the seeds. Peak memory of
one ask is measured in a fresh process per (n, arm) (``--memory``).

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

BUDGET = 1024 * 2**20
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


def ask(name: str, n: int, seed: int, max_train: int | None) -> dict[str, Any]:
    X, y = history(name, n, seed)
    dim = X.shape[1]
    request = ProposalRequest(
        bounds=np.array([[0.0] * dim, [1.0] * dim]),
        count=1,
        seed=seed,
        n_issued=n,
        X=X,
        y=y,
        failed=empty_history(dim),
        pending=empty_history(dim),
        options={"max_train": max_train} if max_train else {},
        memory_bytes=BUDGET,
    )
    started = time.perf_counter()
    proposal = QLogEIProposer().propose(request)
    seconds = time.perf_counter() - started
    value = float(scaled(name, proposal.candidates)[0])
    best = float(y.max())
    return {
        "method": proposal.info[0]["method"],
        "reason": proposal.info[0].get("reason", ""),
        "seconds": seconds,
        "gain": (value - best) / (optimum(name) - best),
    }


def peak_memory(name: str, n: int, max_train: int | None) -> float:
    """MB the ask adds to a fresh process's peak resident memory."""
    code = (
        "import resource, sys, json; from bench.large_history import ask, history;"
        f"history({name!r}, {n}, 0); before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss;"
        f"ask({name!r}, {n}, 0, {max_train!r});"
        "print(json.dumps((resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before) / 1024))"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return float(json.loads(done.stdout.strip().splitlines()[-1]))


def quartiles(values: list[float]) -> str:
    return f"{np.median(values):.3f} / {np.percentile(values, 25):.3f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--n", type=int, nargs="+", default=[2000, 10000])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--functions", nargs="+", default=list(FUNCTIONS))
    parser.add_argument("--full-up-to", type=int, default=3000, help="skip the full arm past it")
    parser.add_argument("--memory", action="store_true", help="peak memory per (n, arm)")
    args = parser.parse_args()
    torch.set_num_threads(max(1, torch.get_num_threads()))
    print(
        "| function | n | arm | model asks | fall backs | seconds: median / max "
        "| gain: median / lower quartile |" + (" peak MB |" if args.memory else "")
    )
    print("| --- | --- | --- | --- | --- | --- | --- |" + (" --- |" if args.memory else ""))
    for name in args.functions:
        for n in args.n:
            arms: list[tuple[str, int | None]] = [("subset", None)]
            if n <= args.full_up_to:
                arms.append(("full", n))
            for arm, max_train in arms:
                runs = [ask(name, n, seed, max_train) for seed in range(args.seeds)]
                model = [r for r in runs if not r["method"].startswith("sobol")]
                seconds = [r["seconds"] for r in runs]
                row = (
                    f"| {name} | {n} | {arm} | {len(model)} | {len(runs) - len(model)} "
                    f"| {np.median(seconds):.2f} / {max(seconds):.2f} "
                    f"| {quartiles([r['gain'] for r in runs])} |"
                )
                if args.memory:
                    row += f" {peak_memory(name, n, max_train):.0f} |"
                print(row, flush=True)
                for r in runs:
                    if r["reason"]:
                        print(f"  fall back: {r['reason']}", file=sys.stderr)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss // 1024
    print(f"peak RSS of this process: {peak} MB")


if __name__ == "__main__":
    main()
