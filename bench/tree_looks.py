"""Thompson looks across trees on a robot task (issue 37): examples/multi-structure.yaml
(lift-highest over six candidate trees, the fast learner, 15 designs) with qei's
``second_looks`` at ``thompson`` (the default) and at ``off``, seed by seed, through a
real ``adserver`` and real ``adworker`` processes.

Each run: a fresh server on a SQLite file, the example study with the run's proposer
seed and task seed (both the seed) and ``second_looks`` set, ``--workers`` workers
(one by default, so a run's designs do not depend on which evaluation ends first).
bench/design_suite.py measures the looks on synthetic objectives; this checks them
where the service is used, on a simulated robot.

Report: per arm the best score's lower quartile, median and upper quartile, how many
seeds each arm beat the other by more than 0.005, the Wilcoxon signed-rank p of the
paired bests, and how many asks of the ``thompson`` arm were looks.

Results append to bench/results/tree_looks.jsonl (a rerun skips the runs it has);
``--report`` prints the table. Run: ``.venv/bin/python bench/tree_looks.py`` (20 seeds x
2 arms: about ten minutes on two cores); ``--seeds 1`` to check it runs.
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path
from typing import Any

import yaml
from scipy.stats import wilcoxon

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.paperlib import arms_parser, quantiles, read_jsonl, run_missing  # noqa: E402
from bench.pruning import run_study  # noqa: E402

RESULTS = ROOT / "bench" / "results" / "tree_looks.jsonl"
EXAMPLE = ROOT / "examples" / "multi-structure.yaml"
ARMS = ("thompson", "off")
SAME = 0.005
"""Bests closer than this count as a tie."""


def study_body(arm: str, seed: int) -> dict[str, Any]:
    body = yaml.safe_load(EXAMPLE.read_text(encoding="utf-8"))
    body["name"] = f"tree-looks-{arm}-{seed}"
    body["proposer"] = {**body["proposer"], "seed": seed, "options": {"second_looks": arm}}
    body["task"] = {**body["task"], "seed": seed}
    return body


def run_one(arm: str, seed: int, args: argparse.Namespace) -> dict[str, Any]:
    body = study_body(arm, seed)
    info, trials, wall = run_study(body, workers=args.workers, timeout=args.timeout)
    return {
        "arm": arm,
        "seed": seed,
        "max_trials": body["max_trials"],
        "workers": args.workers,
        "best": info.best_value,
        "n_failed": info.n_failed,
        "values": [t["value"] for t in trials],
        "methods": [t["method"] for t in trials],
        "wall_s": wall,
    }


def report(runs: list[dict[str, Any]]) -> str:
    lines = [
        "| arm | seeds | best: lower quartile | median | upper quartile | looks a study |",
        "|---|---|---|---|---|---|",
    ]
    by_arm = {arm: {r["seed"]: r for r in runs if r["arm"] == arm} for arm in ARMS}
    for arm, chosen in by_arm.items():
        if not chosen:
            continue
        q1, median, q3 = quantiles([r["best"] for r in chosen.values()])
        looks = statistics.median(r["methods"].count("thompson") for r in chosen.values())
        lines.append(f"| {arm} | {len(chosen)} | {q1:.3f} | {median:.3f} | {q3:.3f} | {looks:g} |")
    both = sorted(set(by_arm["thompson"]) & set(by_arm["off"]))
    if both:
        gaps = [by_arm["thompson"][s]["best"] - by_arm["off"][s]["best"] for s in both]
        higher = sum(gap > SAME for gap in gaps)
        lower = sum(gap < -SAME for gap in gaps)
        p = wilcoxon(gaps).pvalue if any(gaps) else 1.0
        lines.append(
            f"\nthompson against off, {len(both)} seeds: higher in {higher}, lower in {lower} "
            f"(by more than {SAME}); mean paired gap {statistics.fmean(gaps):+.3f}; "
            f"Wilcoxon signed-rank p = {p:.3f}"
        )
    return "\n".join(lines)


def main() -> None:
    parser = arms_parser(__doc__ or "", ARMS, RESULTS, seeds=20, workers=1, timeout=1800.0)
    args = parser.parse_args()
    runs = read_jsonl(args.results)
    if not args.report:
        cells = [
            {"arm": arm, "seed": seed, "workers": args.workers}
            for seed in range(args.seeds)
            for arm in args.arms
        ]
        run_missing(
            args.results, runs, cells, lambda cell: run_one(cell["arm"], cell["seed"], args)
        )
    print(report([r for r in runs if r["workers"] == args.workers]))


if __name__ == "__main__":
    main()
