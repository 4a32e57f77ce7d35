"""Do the fast learner's scores depend on the code version? Re-scores stored designs.

    .venv/bin/python bench/fast_scores_check.py [--per-task 40]

``bench/results/best_known_evals.jsonl`` holds designs scored by the pinned code
(``bench/results/code_ref``). This script scores the first few of each task again
with the working tree's worker code, same learner (fast), seed and budget, and
prints both values. ``bench/paper.py --code REF`` may run a proposer from a later
commit against the pinned best-known targets only when the scores agree.

Forty a task (about 50 s in all): four a task agreed within 0.0026 after the spawn
pose changed (98744ce), while forty found lift-highest designs 0.05 apart and a study's
best design 0.30 apart (bench/RESULTS.md, "Stand-up and lift-highest with today's
proposer").
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.best_known import evaluate_design
from bench.paperlib import RESULTS, read_jsonl


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--per-task", type=int, default=40)
    parser.add_argument(
        "--tolerance", type=float, default=0.0, help="largest difference taken as agreeing"
    )
    args = parser.parse_args()
    taken: dict[str, int] = {}
    worst = 0.0
    for record in read_jsonl(RESULTS / "best_known_evals.jsonl"):
        if record["learner"] != "fast" or taken.get(record["task"], 0) >= args.per_task:
            continue
        taken[record["task"]] = taken.get(record["task"], 0) + 1
        again = evaluate_design(
            record["task"],
            record["structure"],
            record["x"],
            "fast",
            record["seed"],
            record["train_steps"],
        )["value"]
        worst = max(worst, abs(again - record["value"]))
        print(f"{record['key']}: pinned {record['value']:.12g}, now {again:.12g}")
    print(f"largest difference: {worst:.3g}")
    return 0 if worst <= args.tolerance else 1


if __name__ == "__main__":
    raise SystemExit(main())
