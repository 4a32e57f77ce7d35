"""walk-forward: a design that can move travels along +x, one that cannot stays put,
episodes are the seed's, and the task's clock and termination do what they say."""

from __future__ import annotations

import math

import numpy as np
import pytest

from adworker import designs
from adworker.constant_search import ConstantTargetSearch
from adworker.evaluate import evaluate_job
from adworker.learners import evaluate_policy
from tests.workers.robots import HALF_PI, make_job

ACROSS = designs.tree_design(
    [("a", "b"), ("b", "c"), ("c", "d")],
    {"b": (HALF_PI, HALF_PI), "c": (HALF_PI, HALF_PI), "d": (HALF_PI, HALF_PI)},
    effort=10.0,
)
"""Four links, every axis across the chain and horizontal: it can inch and flip forward."""
ALONG = designs.tree_design(
    [("a", "b"), ("b", "c"), ("c", "d")],
    {"b": (0.0, 0.0), "c": (0.0, 0.0), "d": (0.0, 0.0)},
    effort=10.0,
)
"""Every axis along the links: the joints only roll the cylinders, sideways."""


def _swing(observation: np.ndarray, joints: int) -> np.ndarray:
    """Every joint follows the task's clock (the observation's last two values)."""
    return np.full(joints, observation[-2], dtype=np.float32)


def _fast_distances(env, seeds: list[int]) -> list[float]:
    distances = []
    for seed in seeds:
        trained = ConstantTargetSearch().train(env, steps=512, seed=seed)
        episodes = evaluate_policy(env, trained.policy, [100 + seed, 200 + seed])
        distances.append(float(np.mean([episode.score for episode in episodes])))
    return distances


def test_the_fast_learner_walks_a_design_that_can_and_not_one_that_cannot(env_of) -> None:
    across = env_of("walk-forward", ACROSS)
    along = env_of("walk-forward", ALONG)
    try:
        assert across.gait_period == 0.8
        across_distances = _fast_distances(across, [0, 1, 2])
        along_distances = _fast_distances(along, [0, 1, 2])
    finally:
        across.close()
        along.close()
    assert min(across_distances) > 0.2, across_distances
    assert max(abs(distance) for distance in along_distances) < 0.05, along_distances


def test_a_robot_that_holds_still_goes_nowhere(env_of) -> None:
    env = env_of("walk-forward", ACROSS)
    try:
        (episode,) = evaluate_policy(env, lambda observation: np.zeros(3, np.float32), [5])
    finally:
        env.close()
    assert len(episode.metric) == env.episode_steps
    assert abs(episode.score) < 0.005
    assert episode.score == episode.metric[-1]  # the distance at the end, not a mean


def test_episodes_are_the_seeds_and_the_return_is_the_distance(env_of) -> None:
    env = env_of("walk-forward", ACROSS)
    try:
        joints = env.joint_count
        first, again, other = (
            evaluate_policy(env, lambda o: _swing(o, joints), [seed])[0] for seed in (3, 3, 4)
        )
    finally:
        env.close()
    assert first.metric == again.metric
    assert first.metric != other.metric
    assert first.episode_return == pytest.approx(first.score, abs=1e-9)
    assert first.metric[0] != first.metric[-1]  # it moved


def test_the_observation_ends_with_the_gait_clock(env_of) -> None:
    env = env_of("walk-forward", ACROSS, gait_period=0.4)
    stand_up = env_of("stand-up", "arch_chain")
    try:
        observation, _ = env.reset(seed=0)
        assert tuple(observation[-2:]) == (0.0, 1.0)
        for step in range(1, 4):
            observation, *_ = env.step(np.zeros(3, np.float32))
            phase = 2 * math.pi * step * env.sim.control_period / 0.4
            assert observation[-2:] == pytest.approx([math.sin(phase), math.cos(phase)], abs=1e-6)
        # The same robot senses the same things in every free-base task; the clock is extra.
        assert stand_up.gait_period is None
        own = env.robot.observation_size()
        assert env.observation_space.shape == (own + 2,)
    finally:
        env.close()
        stand_up.close()


def test_a_robot_flung_above_max_height_ends_its_episode(env_of) -> None:
    env = env_of("walk-forward", ACROSS, max_height=0.1)
    try:
        joints = env.joint_count
        observation, _ = env.reset(seed=0)
        steps = 0
        terminated = truncated = False
        while not (terminated or truncated):
            observation, _, terminated, truncated, info = env.step(_swing(observation, joints))
            steps += 1
        distance = env.record.metric[-1]
    finally:
        env.close()
    assert terminated and steps < env.episode_steps
    assert info["score"] == distance


def test_a_walk_forward_job_from_the_example_study(tmp_path) -> None:
    specs = {f"{name}.length": 0.35 for name in "abcd"}
    for child in "bcd":
        specs[f"{child}.joint.axis_theta"] = HALF_PI
        specs[f"{child}.joint.axis_phi"] = HALF_PI
    job = make_job("walk-forward", specs, train_steps=256, eval_episodes=2)
    evaluation = evaluate_job(job, tmp_path, render=False)
    assert evaluation.value == pytest.approx(
        np.mean([episode.metric[-1] for episode in evaluation.episodes])
    )
    assert evaluation.value > 0.05
    assert evaluation.metrics["train_steps"] == 256
    # the share of its evaluation episodes that ended fallen: this chain never rolls over
    assert evaluation.metrics["task.fell"] == 0.0
