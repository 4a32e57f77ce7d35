"""What fitting a long history's hyperparameters on a subset costs (issue 26).

For n observations of the ask-latency benchmark's test function (``bench/asklatency.py``,
d = 6, a little noise), qei's GP is fitted cold twice: on every observation, and as qei
fits a long history, on ``gpfit.FIT_POINTS`` of them (``gpfit.fit_subset``), both then
conditioned on all n. Reported: fit CPU seconds and the held-out error (RMSE and mean
negative log predictive density on 500 fresh points) of each, side by side.

Run: ``.venv/bin/python bench/fit_subset.py`` (``--n 500 1000``).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from adservice.proposers import gpfit
from adservice.proposers.base import ProposalRequest, empty_history
from adservice.proposers.posterior import Posterior
from adservice.proposers.qei_shared import QEIOptions
from bench.asklatency import objective

TKW: dict[str, Any] = {"dtype": torch.float64, "device": torch.device("cpu")}


def measure(n: int, seed: int, subset: bool) -> tuple[float, float, float]:
    rng = np.random.default_rng([n, seed])
    X = rng.random((n, 6))
    y = objective(X) + 0.01 * rng.normal(size=n)
    test = rng.random((500, 6))
    truth = objective(test)
    request = ProposalRequest(
        bounds=np.array([[0.0] * 6, [1.0] * 6]),
        count=1,
        seed=seed,
        n_issued=n,
        X=X,
        y=y,
        failed=empty_history(6),
        pending=empty_history(6),
    )
    gpfit.clear_caches()
    points = gpfit.FIT_POINTS
    if not subset:
        gpfit.FIT_POINTS = n  # every observation
    try:
        started = time.thread_time()
        model, _ = gpfit.fit_outcome(request, QEIOptions(), request.bounds, X, y, TKW, None)
        seconds = time.thread_time() - started
    finally:
        gpfit.FIT_POINTS = points
    with torch.no_grad():
        inputs = torch.as_tensor(np.column_stack([np.zeros(len(test)), test]), **TKW)
        mean, sigma = (t.numpy() for t in Posterior(model).mean_sigma(inputs))
    rmse = float(np.sqrt(np.mean((mean - truth) ** 2)))
    sigma = np.sqrt(sigma**2 + 0.01**2)
    nlpd = float(np.mean(0.5 * np.log(2 * np.pi * sigma**2) + 0.5 * ((truth - mean) / sigma) ** 2))
    return seconds, rmse, nlpd


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--n", nargs="+", type=int, default=[500, 1000])
    parser.add_argument("--seeds", type=int, default=3)
    args = parser.parse_args()
    torch.set_num_threads(1)
    print("| n | seed | fit CPU s: all / qei | RMSE: all / qei | NLPD: all / qei |")
    print("| --- | --- | --- | --- | --- |")
    for n in args.n:
        for seed in range(args.seeds):
            full, part = measure(n, seed, False), measure(n, seed, True)
            print(
                f"| {n} | {seed} | {full[0]:.2f} / {part[0]:.2f} | {full[1]:.4f} / {part[1]:.4f} "
                f"| {full[2]:.3f} / {part[2]:.3f} |",
                flush=True,
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
