"""Ask latency of ``qei`` with two objectives (qLogNEHVI), in-process (no HTTP).

Issue 17's goal: an ask of q = 1 at n = 80 observations of m = 2 objectives under
1 s. Each round calls the proposer on ZDT1 (d = 4 by default) with n observations:
the same first n - 1 points every round and a different last one, so from the
second round on each outcome's GP warm-starts from the previous round's fit, as
the next ask of a running study does (the first round fits cold and is part of
the figures). Printed: the median and the worst of the wall time and of the
thread's CPU time (the ask runs in one thread with one torch thread, so on an
idle machine the wall time is the CPU time; on a shared one the wall time also
counts the waits for a core), and the median fit and acquisition seconds.

Run: ``.venv/bin/python bench/mo_asklatency.py`` (about a minute);
``--n 80 --d 4 --q 1 --rounds 10 --constraints 1`` are the defaults but the last
(0): ``--constraints 1`` adds the constraint x0 >= 0.5 (one more GP).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "service"))
sys.path.insert(0, str(ROOT / "client"))

from adservice.proposers import get_proposer  # noqa: E402
from adservice.proposers.base import ProposalRequest, empty_history  # noqa: E402
from adservice.proposers.qei import clear_caches  # noqa: E402


def zdt1(X: np.ndarray) -> np.ndarray:
    """ZDT1's two objectives, negated (maximised)."""
    f1 = X[:, 0]
    g = 1.0 + 9.0 * X[:, 1:].mean(axis=1)
    return -np.column_stack([f1, g * (1.0 - np.sqrt(f1 / g))])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--n", type=int, default=80)
    parser.add_argument("--d", type=int, default=4)
    parser.add_argument("--q", type=int, default=1)
    parser.add_argument("--rounds", type=int, default=10)
    parser.add_argument("--constraints", type=int, choices=[0, 1], default=0)
    parser.add_argument("--options", type=json.loads, default={}, help="qei options (JSON)")
    args = parser.parse_args()

    clear_caches()
    proposer = get_proposer("qei")
    rng = np.random.default_rng(0)
    fixed = rng.random((args.n - 1, args.d))
    bounds = np.array([np.zeros(args.d), np.ones(args.d)])
    walls, cpus, fits, acqs = [], [], [], []
    for round_number in range(args.rounds):
        X = np.vstack([fixed, rng.random((1, args.d))])
        objectives = zdt1(X)
        slacks = (0.5 - X[:, :1]) if args.constraints else None
        request = ProposalRequest(
            bounds=bounds,
            count=args.q,
            seed=1,
            n_issued=args.n,
            X=X,
            y=objectives[:, 0].copy(),
            failed=empty_history(args.d),
            pending=empty_history(args.d),
            n_initial=10,
            objectives=objectives,
            slacks=slacks,
            options=args.options,
        )
        wall, cpu = time.perf_counter(), time.thread_time()
        proposal = proposer.propose(request)
        wall, cpu = time.perf_counter() - wall, time.thread_time() - cpu
        info = proposal.info[0]
        assert info.get("acquisition") == "qLogNEHVI", info
        walls.append(wall)
        cpus.append(cpu)
        fits.append(info["fit_seconds"])
        acqs.append(info["acq_seconds"])
        print(
            f"round {round_number}: wall {wall:.3f} s, cpu {cpu:.3f} s, "
            f"fit {info['fit']} {info['fit_seconds']:.3f} s, acq {info['acq_seconds']:.3f} s, "
            f"front {info['n_pareto']}, baseline {info['n_baseline']}"
        )
    print(
        f"qei qLogNEHVI, n={args.n}, m=2, d={args.d}, q={args.q}, "
        f"constraints={args.constraints}, {args.rounds} rounds: "
        f"wall median {statistics.median(walls):.3f} s (max {max(walls):.3f}), "
        f"cpu median {statistics.median(cpus):.3f} s (max {max(cpus):.3f}), "
        f"fit median {statistics.median(fits):.3f} s, acq median {statistics.median(acqs):.3f} s"
    )


if __name__ == "__main__":
    main()
