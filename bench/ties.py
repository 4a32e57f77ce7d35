"""Tied limbs (issue 28): the quadruped with its legs tied (``same_as``, ``mirror``)
against the same robot with every leg searched on its own, through a real ``adserver``
and real ``adworker`` processes.

Each run: a fresh server on a SQLite file, one managed study of examples/quadruped.yaml
(walk-forward, the fast learner) with the run's proposer and seed, ``--trials``
evaluations, ``--workers`` workers. The ``untied`` arm is the same file with every
``same_as`` and ``mirror`` removed (each instance gets its source's part): 24
dimensions against the tied robot's 6; both arms build the same robots when the untied
one happens to pick symmetric legs.

Goal (issue 28): the tied study's median best above the untied one's (10 seeds, 30
evaluations). Report: the best score's lower quartile, median and upper quartile per
arm, and in how many seeds the tied arm beat the untied one.

Results append to bench/results/ties.jsonl (a rerun skips the runs it has); ``--report``
prints the table. Run: ``.venv/bin/python bench/ties.py`` (10 seeds x 2 arms: about an
hour on two cores); ``--seeds 2 --trials 8`` to check it runs.
"""

from __future__ import annotations

import argparse
import copy
import statistics
import sys
from pathlib import Path
from typing import Any

import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from adclient.design import DesignSpace  # noqa: E402
from bench.paperlib import arms_parser, quantiles, read_jsonl, run_missing  # noqa: E402
from bench.pruning import run_study  # noqa: E402

RESULTS = ROOT / "bench" / "results" / "ties.jsonl"
EXAMPLE = ROOT / "examples" / "quadruped.yaml"
ARMS = ("tied", "untied")


def untied(space: dict[str, Any]) -> dict[str, Any]:
    """The space with every instance searched on its own (its tie source's part)."""
    space = copy.deepcopy(space)
    by_name = {instance["name"]: dict(instance) for instance in space["instances"]}
    for instance in space["instances"]:
        source = by_name[instance["name"]]
        while "same_as" in source:
            source = by_name[source["same_as"]]
        instance["part"] = source["part"]
        instance.pop("same_as", None)
        instance.pop("mirror", None)
    return space


def study_body(arm: str, proposer: str, seed: int, trials: int) -> dict[str, Any]:
    body = yaml.safe_load(EXAMPLE.read_text(encoding="utf-8"))
    if arm == "untied":
        body["space"] = untied(body["space"])
    body["name"] = f"ties-{arm}-{proposer}-{seed}"
    body["max_trials"] = trials
    body["proposer"] = {"name": proposer, "seed": seed}
    if proposer == "qei":
        body["proposer"]["n_initial"] = 4
    return body


def run_one(arm: str, proposer: str, seed: int, args: argparse.Namespace) -> dict[str, Any]:
    body = study_body(arm, proposer, seed, args.trials)
    info, trials, wall = run_study(body, workers=args.workers, timeout=args.timeout)
    return {
        "arm": arm,
        "proposer": proposer,
        "seed": seed,
        "max_trials": args.trials,
        "dimensions": len(DesignSpace.model_validate(body["space"]).free_specs()),
        "best": info.best_value,
        "n_failed": info.n_failed,
        "values": [t["value"] for t in trials],
        "wall_s": wall,
    }


def report(runs: list[dict[str, Any]]) -> str:
    lines = [
        "| proposer | arm | dimensions | seeds | best: lower quartile | median | upper quartile |",
        "|---|---|---|---|---|---|---|",
    ]
    for proposer in sorted({run["proposer"] for run in runs}):
        for arm in ARMS:
            chosen = [r for r in runs if r["proposer"] == proposer and r["arm"] == arm]
            if not chosen:
                continue
            q1, median, q3 = quantiles([r["best"] for r in chosen])
            lines.append(
                f"| {proposer} | {arm} | {chosen[0]['dimensions']} | {len(chosen)} | "
                f"{q1:.3f} | {median:.3f} | {q3:.3f} |"
            )
        tied = {
            r["seed"]: r["best"] for r in runs if r["proposer"] == proposer and r["arm"] == "tied"
        }
        free = {
            r["seed"]: r["best"] for r in runs if r["proposer"] == proposer and r["arm"] == "untied"
        }
        both = sorted(set(tied) & set(free))
        if both:
            wins = sum(tied[s] > free[s] for s in both)
            gap = statistics.median(tied[s] - free[s] for s in both)
            lines.append(
                f"\n{proposer}: tied beat untied in {wins} of {len(both)} seeds; median "
                f"paired gap {gap:+.3f} m"
            )
    return "\n".join(lines)


def main() -> None:
    parser = arms_parser(__doc__ or "", ARMS, RESULTS, seeds=10, workers=2, timeout=3600.0)
    parser.add_argument("--trials", type=int, default=30)
    parser.add_argument("--proposers", nargs="+", default=["qei"])
    args = parser.parse_args()
    runs = read_jsonl(args.results)
    if not args.report:
        cells = [
            {"arm": arm, "proposer": proposer, "seed": seed, "max_trials": args.trials}
            for seed in range(args.seeds)
            for proposer in args.proposers
            for arm in args.arms
        ]
        run_missing(
            args.results,
            runs,
            cells,
            lambda cell: run_one(cell["arm"], cell["proposer"], cell["seed"], args),
        )
    print(report([r for r in runs if r["max_trials"] == args.trials]))


if __name__ == "__main__":
    main()
