"""Asks of studies with thousands of observations (issue 37): qei's model-based ask past
``max_train`` observations (the trust region of ``adservice.proposers.trust_region``, and
the subset of ``adservice.proposers.subset``) against the full exact GP and random points,
side by side in one run.

For each test function (Hartmann6 and Rosenbrock in 6 dimensions: their negatives
maximised, through BoTorch's test functions) and each seed, a history of n uniformly
random points (the study a cheap simulator or a function worker makes) is given to
``QLogEIProposer`` in process, and ``--asks`` asks of q = 1 follow, each told its true
value. The arms:

- ``default``: qei's defaults under the default memory budget (1024 MB): past 2048
  observations on cpu, the ``subset`` model, and past 20,000 of them the ``trust`` one;
- ``trust``: ``large_history: trust-region``, past 2048 observations a GP of the 1024
  best, searched in a trust region around the best (``trust-N``: the N best);
- ``subset``: ``large_history: subset``, a GP of a subset (best, nearest the best, random
  rest) of the most the budget holds, at most 2048, searched over the whole box
  (``subset-N``: ``max_train`` N);
- ``full``: ``max_train = n`` (every observation, with the memory budget it needs);
- ``random``: uniform points, what a fall back to Sobol points gave.

Reported per (function, n, arm): how many asks were the model's, the wall seconds per
ask (median, and the most of the asks after each study's first, cold one; and the first
asks' most), the process's CPU seconds per ask (what a quiet machine's wall time would
be: torch runs one thread; on a machine others load, the wall time is longer), the most
memory one ask added (resident, sampled every 2 ms) beside
``memory.memory_need``'s estimate for its training size, where the best asked point
falls among the history's values (percentile: 100 is better than every one) and the
fraction of the gap between the history's best and the optimum the asks closed (0:
none; 1: all), median and lower quartile over the seeds.

Run: ``.venv/bin/python bench/large_history.py`` (``--n 3000 10000 100000 --seeds 5``).
"""

from __future__ import annotations

import argparse
import resource
import threading
import time
from typing import Any

import numpy as np
import torch
from botorch.test_functions import Hartmann, Rosenbrock

from adservice.proposers import gpfit
from adservice.proposers.base import ProposalRequest, empty_history
from adservice.proposers.memory import memory_need
from adservice.proposers.qei import QLogEIProposer
from adservice.proposers.qei_shared import QEIOptions

BUDGET = 64 * 2**30
"""No budget in the way of the full and ``subset-N`` arms: they must run to be compared."""
DEFAULT_BUDGET = 1024 * 2**20
"""The server's default ``AD_ASK_MEMORY_MB``: the ``trust`` and ``subset`` arms' sizes
are what it holds (``subset.train_size``)."""
FUNCTIONS = {"hartmann6": (Hartmann(dim=6), 6), "rosenbrock6": (Rosenbrock(dim=6), 6)}


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


class PeakMemory:
    """The most resident memory this process held while it ran, sampled every 2 ms,
    above what it held at the start (numpy and torch allocations alike)."""

    def __enter__(self) -> PeakMemory:
        self.start = self.peak = resident_mb()
        self._done = threading.Event()
        self._thread = threading.Thread(target=self._sample, daemon=True)
        self._thread.start()
        return self

    def _sample(self) -> None:
        while not self._done.wait(0.002):
            self.peak = max(self.peak, resident_mb())

    def __exit__(self, *_: object) -> None:
        self._done.set()
        self._thread.join()
        self.peak = max(self.peak, resident_mb())

    @property
    def added(self) -> float:
        return self.peak - self.start


def resident_mb() -> float:
    with open("/proc/self/statm") as statm:
        return int(statm.read().split()[1]) * resource.getpagesize() / 2**20


def arm_options(arm: str, n: int, asks: int) -> dict[str, Any]:
    """qei's options of an arm (see the module docstring)."""
    if arm == "full":
        return {"max_train": n + asks}
    model, _, size = arm.partition("-")
    options: dict[str, Any] = {}
    if model in ("trust", "subset"):
        options["large_history"] = "trust-region" if model == "trust" else "subset"
    if size:
        options["max_train"] = int(size)
    return options


def run(name: str, n: int, seed: int, arm: str, asks: int) -> dict[str, Any]:
    """``asks`` asks of q = 1 after the history, each told its true value; ``arm``: see
    the module docstring."""
    X, y = history(name, n, seed)
    dim = X.shape[1]
    best_before = float(y.max())
    gpfit.clear_caches()  # each arm's study starts cold; its later asks warm-start
    methods, seconds, cpu, memory, estimates = [], [], [], [], []
    rng = np.random.default_rng([seed, n, 7])
    options = arm_options(arm, n, asks)
    for k in range(asks):
        started, cpu_started = time.perf_counter(), time.process_time()
        with PeakMemory() as peak:
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
                    options=options,
                    memory_bytes=BUDGET if arm == "full" or "-" in arm else DEFAULT_BUDGET,
                )
                proposal = QLogEIProposer().propose(request)
                candidate = proposal.candidates
                info = proposal.info[0]
                methods.append(info["method"] + (" (degraded)" if info.get("degraded") else ""))
                if "n_train" in info:
                    need = memory_need(
                        QEIOptions.model_validate(options),
                        dim=dim,
                        count=1,
                        n_train=info["n_train"],
                        n_pending=0,
                    )
                    estimates.append(need.bytes / 2**20)
        seconds.append(time.perf_counter() - started)
        cpu.append(time.process_time() - cpu_started)
        memory.append(peak.added)
        X = np.vstack([X, candidate])
        y = np.append(y, scaled(name, candidate))
    gap = optimum(name) - best_before
    asked = y[n:].max()
    return {
        "percentile": 100.0 * float(np.mean(y[:n] < asked)),
        "methods": methods,
        "seconds": seconds,
        "cpu": cpu,
        "memory": memory,
        "estimates": estimates,
        "closed": (float(y.max()) - best_before) / gap,
    }


def quartiles(values: list[float]) -> str:
    return f"{np.median(values):.3f} / {np.percentile(values, 25):.3f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--n", type=int, nargs="+", default=[3000, 10000, 100000])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--asks", type=int, default=5)
    parser.add_argument("--functions", nargs="+", default=list(FUNCTIONS))
    parser.add_argument("--full-up-to", type=int, default=3000, help="skip the full arm past it")
    parser.add_argument(
        "--arms",
        nargs="+",
        help="only these arms (default, trust, trust-N, subset, subset-N, full, random)",
    )
    args = parser.parse_args()
    print(
        "| function | n | arm | model asks (Sobol: other) | s per ask: median / most after "
        "the first / most of the first | CPU s per ask: median / most | MB an ask adds "
        "(estimate) | best asked, percentile of the history: median / lower quartile | gap "
        "closed: median / lower quartile |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    by_seed: dict[tuple[str, int, str], list[float]] = {}
    for name in args.functions:
        for n in args.n:
            arms = args.arms or ["default", "trust", "subset", "full", "random"]
            for arm in [a for a in arms if a != "full" or n <= args.full_up_to]:
                runs = [run(name, n, seed, arm, args.asks) for seed in range(args.seeds)]
                methods = [m for r in runs for m in r["methods"]]
                model = sum(not m.startswith(("sobol", "random")) for m in methods)
                other = sorted({m for m in methods if m.startswith("sobol")})
                seconds = [t for r in runs for t in r["seconds"]]
                later = [t for r in runs for t in r["seconds"][1:]] or [0.0]
                first = [r["seconds"][0] for r in runs]
                cpu = [t for r in runs for t in r["cpu"]]
                memory = max(m for r in runs for m in r["memory"])
                estimate = max((e for r in runs for e in r["estimates"]), default=0.0)
                closed = [r["closed"] for r in runs]
                by_seed[name, n, arm] = closed
                ranks = [r["percentile"] for r in runs]
                print(
                    f"| {name} | {n} | {arm} | {model} of {len(methods)}"
                    + (f" ({', '.join(other)})" if other else "")
                    + f" | {np.median(seconds):.2f} / {max(later):.2f} / {max(first):.2f} "
                    f"| {np.median(cpu):.2f} / {max(cpu):.2f} "
                    f"| {memory:.0f} ({estimate:.0f}) "
                    f"| {np.median(ranks):.2f} / {np.percentile(ranks, 25):.2f} "
                    f"| {np.median(closed):.3f} / {np.percentile(closed, 25):.3f} |",
                    flush=True,
                )
    print("\nGap closed, seed by seed (seeds 0 on):\n")
    print("| function | n | arm | gap closed |\n| --- | --- | --- | --- |")
    for (name, n, arm), closed in by_seed.items():
        print(f"| {name} | {n} | {arm} | {', '.join(f'{c:.3f}' for c in closed)} |")


if __name__ == "__main__":
    main()
