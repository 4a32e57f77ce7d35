"""bench/transfer.py's bookkeeping: the worker CPU to the scratch arm's 95% mark, the
scratch arm's best at the same CPU, and the goal verdict of issue 27's report; and its
optuna-sb3 arm (issue 38), run end to end at a tiny budget."""

from __future__ import annotations

import math
from argparse import Namespace
from typing import Any

import pytest

from bench.transfer import (
    best_within,
    cpu_to_reach,
    report,
    run_optuna_sb3,
    scratch_at_same_cpu,
    study_body,
)


def run(arm: str, seed: int, trials: list[tuple[float, float | None]]) -> dict[str, Any]:
    """A study record of stand-up/ppo: ``trials`` as (CPU seconds, value or None for a
    failed trial), finished in that order (listed here last first: order comes from the
    finish times)."""
    rows = [
        {
            "finished_at": f"2026-01-01T00:{minute:02d}:00",
            "cpu_seconds": cpu,
            "state": "complete" if value is not None else "failed",
            "value": value,
        }
        for minute, (cpu, value) in enumerate(trials)
    ]
    values = [value for _, value in trials if value is not None]
    return {
        "task": "stand-up",
        "learner": "ppo",
        "arm": arm,
        "seed": seed,
        "trials": list(reversed(rows)),
        "best": max(values) if values else None,
        "worker_cpu_s": sum(cpu for cpu, _ in trials),
        "n_transferred": max(len(trials) - 1, 0),
    }


def row(text: str, arm: str) -> list[str]:
    (line,) = [line for line in text.splitlines() if f"| {arm} |" in line]
    return [cell.strip() for cell in line.strip("|").split("|")]


def test_cpu_to_reach_counts_every_finished_trial_until_the_best_reaches_the_mark() -> None:
    study = run("scratch", 0, [(10.0, 0.2), (5.0, None), (10.0, 0.9), (10.0, 1.0)])
    assert cpu_to_reach(study, 0.9) == 25.0  # the failed trial's CPU counts too
    assert cpu_to_reach(study, 0.95) == 35.0
    assert math.isinf(cpu_to_reach(study, 1.5))


def test_best_within_is_the_best_complete_score_by_that_cpu() -> None:
    study = run("scratch", 0, [(10.0, 0.2), (10.0, 0.5), (10.0, 0.4)])
    assert best_within(study, 5.0) is None
    assert best_within(study, 15.0) == 0.2
    assert best_within(study, 20.0) == 0.5
    assert best_within(study, 1e9) == 0.5


def test_scratch_at_the_same_cpu_pairs_seeds_and_skips_one_scratch_lacks() -> None:
    scratch = [
        run("scratch", 0, [(10.0, 0.1), (10.0, 0.3), (10.0, 0.6)]),
        run("scratch", 1, [(10.0, 0.2), (10.0, 0.4), (10.0, 0.8)]),
    ]
    warm = [
        run("nearest", 0, [(10.0, 0.5), (5.0, 0.7), (5.0, 0.7)]),  # 20 s: scratch had 0.3
        run("nearest", 1, [(10.0, 0.5)]),  # 10 s: scratch had 0.2
        run("nearest", 2, [(10.0, 0.9)]),  # no scratch run of seed 2
    ]
    assert scratch_at_same_cpu(warm, scratch) == "0.2500"
    assert scratch_at_same_cpu(warm[2:], scratch) == "-"


def test_the_goal_is_met_only_with_3x_less_cpu_to_the_mark_and_a_best_in_the_spread() -> None:
    scratch = [run("scratch", seed, [(10.0, 0.5), (10.0, 0.8), (70.0, 1.0)]) for seed in range(3)]
    fast = [run("nearest", seed, [(20.0, 1.0), (5.0, 0.9)]) for seed in range(3)]
    slow = [run("nearest/8", seed, [(20.0, 0.5), (10.0, 0.6), (15.0, 1.0)]) for seed in range(3)]
    never = [run("nearest+asha", seed, [(10.0, 0.5)] * 3) for seed in range(3)]
    text = report(scratch + fast + slow + never)
    # the mark: 95% of the scratch arm's median best (0.95), reached by scratch at 90 s
    assert row(text, "scratch")[8] == "90 (3/3)"
    met = row(text, "nearest")
    assert met[8] == "20 (3/3)" and met[9] == "4.50x less" and met[-1] == "met"
    assert met[5] == "0.8000"  # what scratch had found with nearest's 25 s
    assert row(text, "nearest/8")[9] == "2.00x less" and row(text, "nearest/8")[-1] == "missed"
    missed = row(text, "nearest+asha")
    assert missed[8] == "never (0/3)" and missed[9] == "never" and missed[-1] == "missed"


@pytest.mark.slow
@pytest.mark.e2e
def test_the_optuna_arm_trains_every_design_gpsampler_asks_for() -> None:
    """The optuna-sb3 arm end to end at a tiny budget: a real server keeps the trials,
    each design GPSampler asks for is trained from scratch in a worker process (PPO's
    budget here) and told back with its CPU seconds; no design is the service's own."""
    body = study_body("stand-up", "ppo", "optuna-sb3", 0, Namespace(train_steps=256, trials=3))
    info, trials, wall = run_optuna_sb3(body, seed=0, workers=2)
    assert info.n_complete == 3 and wall > 0
    assert sorted(t["number"] for t in trials) == [0, 1, 2]
    for trial in trials:
        assert trial["state"] == "complete" and trial["cpu_seconds"] > 0
        assert trial["train_steps"] >= 256 and trial["shared_from"] is None
