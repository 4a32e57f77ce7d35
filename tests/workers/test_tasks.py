"""The task environments: Gymnasium conformance, determinism, and what they measure."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from adworker import designs

BUILT_IN = ["diagonal-gesture", "lift-highest", "stand-up", "walk-forward"]


@pytest.mark.parametrize("task", BUILT_IN)
def test_env_checker_passes(task: str, env_of) -> None:
    env = env_of(task, "crossed_chain")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            warnings.filterwarnings("ignore", message=".*infinity.*")
            warnings.filterwarnings("ignore", message=".*not having a spec.*")
            check_env(env)
    finally:
        env.close()


def test_close_disconnects_and_envs_do_not_share_a_client(env_of) -> None:
    import pybullet

    first = env_of("stand-up", "arch_chain")
    second = env_of("stand-up", "arch_chain")
    first_client = first.sim.client
    assert first_client != second.sim.client
    assert pybullet.isConnected(physicsClientId=first_client)
    first.close()
    assert not pybullet.isConnected(physicsClientId=first_client)
    second.reset(seed=0)
    second.step(np.zeros(2, dtype=np.float32))
    second.close()


def _trace(env, action, seed: int) -> list[float]:
    env.reset(seed=seed)
    for _ in range(env.episode_steps):
        env.step(np.asarray(action, dtype=np.float32))
    return list(env.record.metric)


@pytest.mark.parametrize("task", BUILT_IN)
def test_episodes_depend_only_on_seed_and_policy(task: str, env_of) -> None:
    env = env_of(task, "arch_chain")
    try:
        first = _trace(env, [0.4, 0.4], seed=7)
        _trace(env, [-1.0, 1.0], seed=3)  # something else in between
        again = _trace(env, [0.4, 0.4], seed=7)
        other_seed = _trace(env, [0.4, 0.4], seed=8)
    finally:
        env.close()
    assert first == again
    assert first != other_seed


def test_stand_up_arch_lifts_b_and_along_links_cannot(env_of) -> None:
    action = [0.7, 0.7]  # both joints bent ~63 degrees, the same way: an arch
    arch = env_of("stand-up", "arch_chain")
    along = env_of("stand-up", "along_links_chain")
    try:
        _trace(arch, action, seed=0)
        arch_score = arch.record.score()
        snapshot = arch.snapshot()
        a, c = arch.robot.link_position("a"), arch.robot.link_position("c")
        assert snapshot.touching[a] and snapshot.touching[c]
        along_scores = []
        for candidate in ([0.7, 0.7], [-0.7, -0.7], [1.0, -1.0], [0.0, 0.0]):
            _trace(along, candidate, seed=0)
            along_scores.append(along.record.score())
    finally:
        arch.close()
        along.close()
    radius = 0.04
    assert arch_score > 0.3  # b's centre well off the ground
    assert max(along_scores) < radius + 0.01  # b stays lying at its radius


def test_stand_up_counts_zero_while_a_foot_is_off_the_ground(env_of) -> None:
    env = env_of("stand-up", "arch_chain")
    try:
        # Bent the other way the chain lies on b with a and c in the air (a "U").
        _trace(env, [-0.5, -0.5], seed=0)
        metric = env.record.metric
        snapshot = env.snapshot()
    finally:
        env.close()
    assert not (snapshot.touching[0] and snapshot.touching[2])
    assert metric[-1] == 0.0


def test_diagonal_gesture_crossed_axes_reach_the_diagonal_parallel_ones_cannot(env_of) -> None:
    crossed = env_of("diagonal-gesture", "crossed_chain")
    parallel = env_of("diagonal-gesture", "parallel_chain")
    try:
        grid = np.linspace(-1, 1, 9)
        crossed_best = max(_score(crossed, [u, v]) for u in grid for v in grid)
        parallel_best = max(_score(parallel, [u, v]) for u in grid for v in grid)
    finally:
        crossed.close()
        parallel.close()
    # Parallel axes along x keep c in the y-z plane: at best cos = sqrt(2/3).
    assert parallel_best <= math.sqrt(2 / 3) + 0.01
    assert crossed_best > 0.95


def _score(env, action) -> float:
    _trace(env, action, seed=0)
    return env.record.score()


def test_lift_highest_works_on_a_branching_tree(env_of) -> None:
    star = designs.tree_design(
        [("a", "b"), ("a", "c"), ("a", "d")],
        {"b": (math.pi / 2, math.pi / 2), "c": (math.pi / 2, 0.0), "d": (0.0, 0.0)},
        position={"b": 1.0, "c": 0.5, "d": 1.0},
    )
    env = env_of("lift-highest", star)
    try:
        assert env.action_space.shape == (3,)
        rest = _score(env, [0.0, 0.0, 0.0])
        raised = max(_score(env, [u, v, 0.0]) for u in (-1, 1) for v in (-1, 1))
    finally:
        env.close()
    assert rest == pytest.approx(0.08, abs=0.01)  # lying flat: top of a cylinder of radius 0.04
    assert raised > rest + 0.1


def test_render_image_is_a_picture_of_the_robot(env_of) -> None:
    env = env_of("stand-up", "arch_chain", render_mode="rgb_array")
    try:
        env.reset(seed=0)
        image = env.render()
    finally:
        env.close()
    assert image is not None
    assert image.shape == (240, 320, 3)
    assert image.dtype == np.uint8
    assert len(np.unique(image.reshape(-1, 3), axis=0)) > 10  # not a blank frame
