"""track-velocity (issue 60): locomotion at a commanded speed, on PyBullet and MuJoCo.
A robot that stands still tracks nothing, one that dives forward onto its side tracks
only while upright (walk-forward's fall rule), tracking is best near the commanded
speed, and the energy term costs what the motors' power was: the score is what
docs/method.md says it is."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from tests.workers import test_engines
from tests.workers.test_falls import DIVE, run, standing_quadruped
from tests.workers.test_walk_forward import ACROSS

ENGINES = test_engines.ENGINES
engine_env = test_engines.engine_env
"""The fixture of tests/workers/test_engines.py: an env built as the worker builds it."""


@pytest.mark.parametrize("engine", ENGINES)
def test_standing_still_and_diving_forward_track_no_speed(engine_env, engine: str) -> None:
    walker = engine_env("track-velocity", standing_quadruped(), engine)
    still, _ = run(walker, None)
    assert abs(still) < 0.02 and walker.task_metrics()["fell"] == 0.0
    # without the fall rule the dive's ground counts as moving at speed
    unchecked = engine_env("track-velocity", standing_quadruped(), engine, fall_angle=90.0)
    free_dive, _ = run(unchecked, DIVE)
    assert free_dive > 0.15
    dive, _ = run(walker, DIVE)
    assert walker.task_metrics()["fell"] == 1.0
    # it tracked only in the few steps it was upright: most of the episode it lay fallen
    assert dive < 0.1 and dive < free_dive - 0.1


def crawl(env) -> tuple[float, dict[str, float]]:
    """An inchworm's crawl forward (each joint on the gait clock, a radian behind the
    last): the command is not looked at, so every env crawls alike."""
    observation, _ = env.reset(seed=0)
    for _ in range(env.episode_steps):
        clock = math.atan2(observation[-2], observation[-1])
        action = [math.sin(clock - k) for k in range(env.joint_count)]
        observation, *_ = env.step(np.array(action, dtype=np.float32))
    return env.record.score(), dict(env.task_metrics())


@pytest.mark.parametrize("engine", ENGINES)
def test_tracking_is_best_near_the_commanded_speed_and_power_costs_its_share(
    engine_env, engine: str
) -> None:
    def score(speed: float, energy_weight: float) -> tuple[float, dict[str, float]]:
        env = engine_env(
            "track-velocity",
            ACROSS,
            engine,
            speeds=[speed],
            energy_weight=energy_weight,
            episode_steps=48,
        )
        return crawl(env)

    _, measured = score(1.0, 0.0)
    speed = measured["speed"]
    assert speed > 0.05  # it crawls forward
    near, metrics = score(speed, 0.0)
    far, _ = score(4 * speed, 0.0)
    assert near > far + 0.15 and near > 0.3
    # each step's metric is its tracking less energy_weight x its power fraction, and the
    # score their mean: a weight of 1 takes off the episode's mean power, no more
    costed, _ = score(speed, 1.0)
    assert metrics["power"] > 0.05
    assert near - costed == pytest.approx(metrics["power"], rel=1e-6)


def test_the_speed_commanded_is_observed_and_changes_on_schedule(engine_env) -> None:
    env = engine_env("track-velocity", ACROSS, "pybullet", speeds=[0.1, 0.3], episode_steps=8)
    observation, _ = env.reset(seed=0)
    seen = [float(observation[-3])]  # before the gait clock's sin and cos
    for _ in range(env.episode_steps - 1):
        observation, *_ = env.step(np.zeros(env.joint_count, dtype=np.float32))
        seen.append(float(observation[-3]))
    assert seen == pytest.approx([0.1] * 4 + [0.3] * 4)


def test_the_score_is_the_mean_over_the_episodes_steps_as_documented(engine_env) -> None:
    """docs/method.md quotes the rule the curve names, and the score computes it: an
    episode ended early by max_height counts its missing steps as 0."""
    method = (Path(__file__).resolve().parents[2] / "docs" / "method.md").read_text()
    env = engine_env("track-velocity", ACROSS, "pybullet", episode_steps=24)
    assert f'"{env.score_text}"' in method.replace("\n  ", " ")
    score, _ = crawl(env)
    assert score == pytest.approx(float(np.mean(env.record.metric)))
    flung = engine_env("track-velocity", ACROSS, "pybullet", episode_steps=24, max_height=0.1)
    flung.reset(seed=0)
    for _ in range(24):
        *_, terminated, _, _ = flung.step(np.ones(flung.joint_count, dtype=np.float32))
        if terminated:
            break
    metric = flung.record.metric
    assert terminated and len(metric) < 24
    assert flung.record.score() == pytest.approx(sum(metric) / 24)
