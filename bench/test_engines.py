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
    arms = ("random", "ppo", "random-batch", "physics-batch", "ppo-2", "ppo-4")
    arms += ("ppo-batch-2", "ppo-batch-4")
    for engine in ("pybullet", "mujoco"):
        for arm in arms:
            assert figures[f"stand-up.{engine}.{arm}"] > 0
        # the goals of issue 59, per batched learner (SB3's PPO on the batch, the lean
        # ppo-batch): the best batched arm over the baseline, the learner's share
        for learner, figure in (("ppo", "batched"), ("ppo-batch", "lean")):
            best = max(figures[f"stand-up.{engine}.{learner}-{count}"] for count in (2, 4))
            speedup = figures[f"stand-up.{engine}.{figure}_over_baseline"]
            assert speedup == best / figures["stand-up.pybullet.ppo"]
            share = figures[f"stand-up.{engine}.{figure}_learner_share"]
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
    for engine in ("mujoco", "pybullet"):
        assert f"batched {engine} PPO" in done.stdout and f"lean {engine} PPO" in done.stdout
    # each goal line says the arm's gradient updates per sample beside today's
    assert "gradient updates per sample 0.1250 (today's 0.1562)" in done.stdout
