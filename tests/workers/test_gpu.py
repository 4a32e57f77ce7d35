"""The GPU path on Warp's CPU device (issue 59): designs of one tree in one MuJoCo Warp
batch play the CPU MuJoCo engine's episodes, and a PPO with one policy per design trains
on the batch. Skipped, saying why, where the ``gpu`` extra (mujoco-warp) is missing."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip(
    "mujoco_warp", reason="the GPU path needs the gpu extra: pip install -e '.[gpu]'"
)

import torch

from adworker import designs
from adworker.gpu.ppo import DesignPolicies, GpuPPOOptions, evaluate, train
from adworker.gpu.warp_batch import WarpBatch

pytestmark = pytest.mark.xdist_group("warp")
"""One test process compiles Warp's kernels once (about 26 s of CPU on a fresh machine)
and runs every test of the batch."""

TOLERANCE = 2e-3
"""m (a link's height) and rad (a joint angle): float32 in the batch, float64 on the CPU
engine; measured over these episodes at most 4e-5. A design tumbling under random actions, or an
arch balanced on its feet's tips, parts from its CPU twin after some 20 control steps
(whether a foot touches flips on a float's difference): chaos, not a difference in the
model, so this test drives a pose that holds."""


def fold_actions(steps: int) -> np.ndarray:
    """The joints bent opposite ways over 8 control steps, then held: the middle link
    lifts with both feet down."""
    ramp = np.minimum(1.0, np.arange(steps)[:, None] / 8)
    return (ramp * np.array([[0.7, -0.7]])).astype(np.float32)


def test_each_world_of_a_warp_batch_of_two_designs_plays_the_cpu_engines_episode(env_of):
    shorter = designs.arch_chain(length=0.3, mass=1.5)
    envs = [
        env_of("stand-up", "arch_chain", simulator="mujoco"),
        env_of("stand-up", shorter, simulator="mujoco"),
    ]
    batch = WarpBatch(envs, 2, device="cpu")
    assert {"body_mass", "geom_size", "body_pos"} <= set(batch.per_world_fields)
    steps = envs[0].episode_steps
    actions = fold_actions(steps)
    observation = batch.reset(seed=7)
    heights, angles = [], []
    scores = None
    for t in range(steps):
        observation, reward, scores = batch.step(torch.as_tensor(actions[t]).repeat(4, 1))
        heights.append(reward.numpy().copy())
        angles.append(observation[:, : batch.joints].numpy().copy())
    assert scores is not None  # the episode ended with its last step
    lifted = np.array(heights)
    assert lifted.max() > 0.1  # the arch stood up: a height that can disagree
    for world in range(4):
        env = envs[world // 2]
        env.reset(seed=7 + world)
        cpu_heights, cpu_angles = [], []
        for t in range(steps):
            cpu_observation, reward, _, truncated, info = env.step(actions[t])
            cpu_heights.append(reward)
            cpu_angles.append(cpu_observation[: batch.joints])
        assert truncated
        np.testing.assert_allclose(lifted[:, world], cpu_heights, atol=TOLERANCE)
        # The batch's last observation is the next episode's first (its worlds reset).
        np.testing.assert_allclose(np.array(angles)[:-1, world], cpu_angles[:-1], atol=TOLERANCE)
        assert abs(float(scores[world]) - info["score"]) < TOLERANCE
    # The two designs are other worlds: the shorter arch lifts its middle less high.
    assert lifted[:, :2].max() > lifted[:, 2:].max() + 0.02


def test_a_batch_refuses_designs_of_another_tree_and_what_it_does_not_compute(env_of):
    arch = env_of("stand-up", "arch_chain", simulator="mujoco")
    star = designs.tree_design(
        [("a", "b"), ("a", "c"), ("a", "d")],
        {"b": (1.0, 0.0), "c": (1.0, 2.0), "d": (1.0, 4.0)},
    )
    with pytest.raises(ValueError, match="not of one tree"):
        WarpBatch([arch, env_of("stand-up", star, simulator="mujoco")], 1, device="cpu")
    with pytest.raises(ValueError, match="MuJoCo's world"):
        WarpBatch([env_of("stand-up", "arch_chain")], 1, device="cpu")
    with pytest.raises(ValueError, match="no batched metric"):
        WarpBatch([env_of("lift-highest", "arch_chain", simulator="mujoco")], 1, device="cpu")
    with pytest.raises(ValueError, match="at most"):
        WarpBatch([arch], 70_000, device="cpu")
    assert GpuPPOOptions(steps=0).problems() == [
        "steps must be 1 to 100000000 env steps per design"
    ]


@pytest.mark.slow
def test_ppo_on_the_batch_trains_each_designs_policy_above_its_untrained_one(env_of):
    # Four copies of one design: four policies, each initialised from its own draws and
    # trained on its own worlds, in one run (Warp's CPU device costs per batch step, about
    # 80 ms, nearly whatever the worlds: four policies cost about what one does).
    envs = [env_of("stand-up", "arch_chain", simulator="mujoco") for _ in range(4)]
    batch = WarpBatch(envs, 16, device="cpu")
    seed = 3
    final_episode = seed + 1_000_000  # the seed of train's scoring episode
    random_policy = evaluate(batch, None, final_episode)
    untrained = DesignPolicies(4, batch.observation_size, batch.joints, 64, seed)
    before = evaluate(batch, untrained, final_episode)  # train's own initial weights
    options = GpuPPOOptions(steps=4096, unroll=16, epochs=8, learning_rate=3e-3, seed=seed)
    _, result = train(batch, options)
    assert result.env_steps >= 4096
    assert len(result.curve) == 4096 // 16 // batch.episode_steps
    gains = [after - start for after, start in zip(result.scores, before, strict=True)]
    # Untrained, the arch lies flat and scores its radius (0.04); random actions toss it
    # about (a foot off the ground scores 0: about 0.012). Trained (seeds 3 and 5 here):
    # every policy above every random-action world's score, the four's mean 0.04 to 0.06
    # over their untrained weights, the best 0.15 to 0.18; a policy of four may stay near
    # flat on this budget, so the mean and the best gain are asserted, not each.
    assert min(result.scores) > max(random_policy), (random_policy, result.scores)
    assert sum(gains) / len(gains) > 0.02, (before, result.scores)
    assert max(gains) > 0.05, (before, result.scores)


@pytest.mark.e2e
def test_a_gpu_worker_trains_two_trials_of_one_tree_in_one_batch_and_tells_each(
    server, tmp_path
) -> None:
    """A real adserver and ``adworker --batch-designs 2`` (on Warp's CPU device): a
    stand-up study on MuJoCo with PPO, its two trials leased together, trained in one
    batch and told, each its own score."""
    from adclient import Client
    from adclient.testing.workers import WorkerProcess
    from tests.workers.robots import stand_up_study

    with Client(server.url) as client:
        study = stand_up_study(
            client, max_trials=2, learner="ppo", simulator="mujoco", train_steps=256
        )
        worker = WorkerProcess(
            server,
            tmp_path,
            "gpu",
            "--batch-designs",
            "2",
            "--worlds-per-design",
            "4",
            "--max-jobs",
            "2",
        )
        try:
            assert worker.wait() == 0, worker.log()
        finally:
            worker.stop()
        trials = client.trials(study.id)
        assert [t.state for t in trials] == ["complete"] * 2, worker.log()
        assert all(t.value is not None and t.value >= 0 for t in trials)
        assert "trained 2 designs together, 256 env steps each" in worker.log()
