"""The split part of bench/evaluation.py (issue 14): ``env.step`` before and after.

The cost of ``env.step`` with the simulator, robot and task apart against the harness
before it (commit ``PRE_SPLIT``), side by side: the split's own commit (``SPLIT``),
the installed harness with the old whole-body velocity clamp put back (so it simulates
what the old code did), and the installed harness as it is. One bench/step_cost.py
process per side (commits extracted with git archive and put first on PYTHONPATH),
all asked for the same episodes (designs, seeds, actions) in turn, the order
rotating, so load on the shared cores falls on each alike; thread CPU time per
control step, and the median of the per-episode ratios to the pre-split one. The
metric traces are compared bit for bit with the pre-split ones.
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from bench.paperlib import snapshot, snapshot_paths
from bench.step_cost import CASES

ROOT = Path(__file__).resolve().parents[1]
PRE_SPLIT = "e54847e667c9c34779b03b97a868169e9ade0e89"
"""The last commit with the pre-split harness (one RobotEnv per task, from the URDF)."""
SPLIT = "e409cc3d58b9a897c56a30cb980004b5146df76f"
"""The split itself, before anything changed what the harness simulates."""
SPLIT_SECTION = "## Simulator, robot and task apart (issue 14)"
SPLIT_GOAL = 1.05
"""The split may cost at most 5% more per control step."""


SPLIT_SIDES = {
    "split": "the split's commit",
    "clamped": "installed, old clamp",
    "now": "installed",
}
"""The harnesses compared with the pre-split one (``before``), as the report names them."""


def bench_split(episodes: int) -> dict[str, Any]:
    """bench/step_cost.py with each harness, all running at once and asked for the same
    episodes in turn; see the module docstring."""
    clean = {key: value for key, value in os.environ.items() if key != "PYTHONPATH"}
    script = [sys.executable, str(ROOT / "bench" / "step_cost.py")]
    commands: dict[str, tuple[list[str], dict[str, str]]] = {
        side: (script, {**clean, "PYTHONPATH": os.pathsep.join(snapshot_paths(snapshot(sha)))})
        for side, sha in (("before", PRE_SPLIT), ("split", SPLIT))
    }
    commands["clamped"] = ([*script, "--whole-body-clamp"], clean)
    commands["now"] = (script, clean)
    sides = {
        side: subprocess.Popen(command, env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE)
        for side, (command, env) in commands.items()
    }

    def answer(side: str) -> dict[str, Any]:
        stdout = sides[side].stdout
        assert stdout is not None
        line: dict[str, Any] = json.loads(stdout.readline())
        return line

    def ask(side: str, request: dict[str, Any]) -> dict[str, Any]:
        stdin = sides[side].stdin
        assert stdin is not None
        stdin.write(json.dumps(request).encode() + b"\n")
        stdin.flush()
        return answer(side)

    names = list(sides)
    try:
        codes = {side: str(answer(side)["code"]) for side in names}
        if len({codes["before"], codes["split"], codes["now"]}) != 3:
            raise SystemExit(f"two sides imported the same harness: {codes}")
        rows = []
        for case in CASES:
            runs: dict[str, list[dict[str, Any]]] = {side: [] for side in names}
            for episode in range(-3, episodes):  # three warm-up episodes first
                turn = episode % len(names)
                for side in names[turn:] + names[:turn]:
                    result = ask(side, {"case": case, "episode": episode + 3})
                    if episode >= 0:
                        runs[side].append(result)
            rows.append(_split_row(case, runs))
    finally:
        for process in sides.values():
            assert process.stdin is not None
            process.stdin.close()
            process.wait()
    return {
        "date": datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "load": os.getloadavg()[0],
        "episodes": episodes,
        "code": {side: Path(code).relative_to(ROOT).as_posix() for side, code in codes.items()},
        "rows": rows,
    }


def _split_row(case: str, runs: dict[str, list[dict[str, Any]]]) -> dict[str, Any]:
    per_step = {
        side: [1e6 * run["seconds"] / run["steps"] for run in side_runs]
        for side, side_runs in runs.items()
    }
    traces = {side: [run["metric"] for run in side_runs] for side, side_runs in runs.items()}
    row: dict[str, Any] = {
        "case": case,
        "before_us_per_step": statistics.median(per_step["before"]),
    }
    shown = [f"  {case:32s} before {row['before_us_per_step']:6.1f} us/step"]
    for side in SPLIT_SIDES:
        paired = sorted(a / b for a, b in zip(per_step[side], per_step["before"], strict=True))
        quarter = len(paired) // 4
        row[side] = {
            "us_per_step": statistics.median(per_step[side]),
            "ratio": statistics.median(paired),
            "quartiles": [paired[quarter], paired[-1 - quarter]],
            "same_traces": traces[side] == traces["before"],
        }
        shown.append(
            f"{side} {row[side]['ratio']:.3f}{'' if row[side]['same_traces'] else ' (differs)'}"
        )
    print("  ".join(shown), flush=True)
    return row


def split_report(split: dict[str, Any]) -> str:
    same_physics = [row[side]["ratio"] for row in split["rows"] for side in ("split", "clamped")]
    worst = max(same_physics)
    code = split["code"]
    lines = [
        SPLIT_SECTION,
        "",
        "Command: `.venv/bin/python bench/evaluation.py --part split --write` (last run"
        f" {split['date']}, load average {split['load']:.1f} at the end on {os.cpu_count()}"
        " cores shared with other engineers' work).",
        "",
        "Thread CPU time of `env.step` per control step (12 physics steps, state read,"
        " metric, reward, observation) with four harnesses side by side: before the split"
        f" (commit {PRE_SPLIT[:7]}, from {code['before']}); the split's commit"
        f" ({SPLIT[:7]}, from {code['split']}); the installed harness ({code['now']})"
        " with the pre-split joint speed limit put back (Bullet's whole-body velocity"
        " clamp: `old clamp`), and as it is. One bench/step_cost.py process each, all"
        " running the same episodes in turn (the order rotating),"
        f" {split['episodes']} episodes of 32 steps per case after three warm-up ones."
        " Median per step; ratio: the median (quartiles) of the per-episode ratio to"
        " before; `=`: every episode's per-step metric equal to before's, bit for bit:",
        "",
        "```",
        f"{'case':31s} {'before':>9s}  "
        + "  ".join(f"{label:<28s}" for label in SPLIT_SIDES.values()).rstrip(),
    ]
    for row in split["rows"]:
        cells = [f"{row['case']:31s} {row['before_us_per_step']:6.1f} us"]
        for side in SPLIT_SIDES:
            low, high = row[side]["quartiles"]
            same = "=" if row[side]["same_traces"] else " "
            cells.append(
                f"{row[side]['us_per_step']:6.1f} us {row[side]['ratio']:.3f}"
                f" ({low:.2f}-{high:.2f}){same}"
            )
        lines.append("  ".join(cells).rstrip())
    lines += [
        "```",
        "",
        f"- Goal (the split costs at most {100 * (SPLIT_GOAL - 1):.0f}% more per control"
        f" step): {'met' if worst <= SPLIT_GOAL else 'not met'}, worst case"
        f" {100 * (worst - 1):+.1f}% (the split's commit, and the installed harness"
        " simulating the same, bit for bit).",
        "- The installed harness as it is simulates differently on purpose: a joint's"
        " speed limit is its motor's, no longer Bullet's velocity clamp of the whole body,"
        " which also held a free base's velocities (commit 35fc49d). That costs the engine"
        " more per step on the free robots (`installed` against `installed, old clamp`:"
        " the same code, only the clamp differs); the fixed arm is unaffected. It is the"
        " price of momentum conserved, not of the split.",
        "",
    ]
    return "\n".join(lines)
