"""bench/engines.py, run as a program on a short budget: a figure per engine and arm, and
the ratio of the two engines', as BENCH lines bench/compare.py reads."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]


def test_the_bench_reports_each_engines_rate_and_their_ratio(tmp_path: Path) -> None:
    rows_file = tmp_path / "rows.json"
    done = subprocess.run(
        [sys.executable, str(REPO_ROOT / "bench" / "engines.py"), "--tasks", "stand-up",
         "--steps", "64", "--ppo-steps", "256", "--worlds", "2,4", "--json", str(rows_file)],
        cwd=REPO_ROOT, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr
    figures = {}
    for line in done.stdout.splitlines():
        if line.startswith("BENCH "):
            figure = json.loads(line.removeprefix("BENCH "))
            figures[figure["metric"]] = figure["value"]
    for engine in ("pybullet", "mujoco"):
        for arm in ("random", "ppo", "random-batch", "ppo-2", "ppo-4"):
            assert figures[f"stand-up.{engine}.{arm}"] > 0
        # the goals of issue 59: the best batched PPO over the baseline, the learner's share
        best = max(figures[f"stand-up.{engine}.ppo-{count}"] for count in (2, 4))
        speedup = figures[f"stand-up.{engine}.batched_over_baseline"]
        assert speedup == best / figures["stand-up.pybullet.ppo"]
        share = figures[f"stand-up.{engine}.batched_learner_share"]
        assert share == 1 - best / figures[f"stand-up.{engine}.random-batch"]
    for arm in ("random", "ppo"):
        ratio = figures[f"stand-up.mujoco.{arm}"] / figures[f"stand-up.pybullet.{arm}"]
        assert figures[f"stand-up.mujoco_over_pybullet.{arm}"] == ratio
    rows = json.loads(rows_file.read_text())["rates"]
    assert [(row["task"], row["engine"]) for row in rows] == [
        ("stand-up", "pybullet"),
        ("stand-up", "mujoco"),
    ]
    assert all(row["frame_skip"] == 12 and row["joints"] == 2 for row in rows)
    assert all(row["random-batch-worlds"] == 4 for row in rows)
    assert "batched mujoco PPO" in done.stdout and "batched pybullet PPO" in done.stdout
