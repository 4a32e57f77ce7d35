"""Batched worlds and PPO on the batch (issue 59), real engines both: world i of a batch
plays the same episodes as one env seeded as it is and given the same actions; the
``ppo`` learner's ``n_envs`` trains on a batch for the same budget, counts every world's
physics steps and closes the worlds it built; and a real adserver and adworker run a
study with it end to end, its curve and checkpoint valid."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from pydantic import ValidationError

from adclient import Client
from adclient.builtin_learners import MAX_BATCH_WORLDS, PPOOptions
from adclient.pruning import CHECKPOINT_ARTIFACT
from adclient.testing.workers import WorkerProcess
from adworker.batched import BatchedEnv
from adworker.learners import PPOLearner
from tests.workers.robots import EXAMPLES

ENGINES = ("pybullet", "mujoco")
EPISODE_STEPS = 6
WORLDS = 3
SEED = 41


def alone(env: Any, seed: int, actions: np.ndarray) -> dict[str, list[Any]]:
    """One env stepped with ``actions`` from a reset seeded ``seed``, reset (unseeded)
    whenever an episode ends, as a batch resets its worlds."""
    observations, rewards, ends, scores = [env.reset(seed=seed)[0]], [], [], []
    for action in actions:
        observation, reward, terminated, truncated, info = env.step(action)
        rewards.append(reward)
        ends.append(terminated or truncated)
        if terminated or truncated:
            scores.append(info["score"])
            observations.append(observation)  # the terminal observation
            observation, _ = env.reset()
        observations.append(observation)
    return {"observations": observations, "rewards": rewards, "ends": ends, "scores": scores}


@pytest.mark.parametrize("task", ["stand-up", "walk-forward"])
@pytest.mark.parametrize("engine", ENGINES)
def test_world_i_plays_the_episodes_of_one_env_with_its_seed_and_actions(
    env_of, engine: str, task: str
) -> None:
    first = env_of(
        task, "arch_chain", simulator=engine, episode_steps=EPISODE_STEPS, init_noise=0.3
    )
    batch = BatchedEnv.of(first, WORLDS)
    try:
        batch.seed(SEED)
        rng = np.random.default_rng(0)
        steps = 2 * EPISODE_STEPS + 2  # two whole episodes and part of a third
        joints = first.action_space.shape[0]
        actions = rng.uniform(-1, 1, (steps, WORLDS, joints)).astype(np.float32)
        played: list[dict[str, list[Any]]] = [
            {"observations": [], "rewards": [], "ends": [], "scores": []} for _ in range(WORLDS)
        ]
        observations = batch.reset()
        for i in range(WORLDS):
            played[i]["observations"].append(observations[i])
        for action in actions:
            observations, rewards, dones, infos = batch.step(action)
            for i in range(WORLDS):
                played[i]["rewards"].append(float(rewards[i]))
                played[i]["ends"].append(bool(dones[i]))
                if dones[i]:
                    played[i]["scores"].append(infos[i]["score"])
                    played[i]["observations"].append(infos[i]["terminal_observation"])
                played[i]["observations"].append(observations[i])
        # worlds seeded apart start apart: the comparison below can fail
        starts = [tuple(played[i]["observations"][0]) for i in range(WORLDS)]
        assert len(set(starts)) == WORLDS, starts
        for i in range(WORLDS):
            single = env_of(
                task, "arch_chain", simulator=engine, episode_steps=EPISODE_STEPS, init_noise=0.3
            )
            try:
                expected = alone(single, SEED + i, actions[:, i])
            finally:
                single.close()
            assert played[i]["ends"] == expected["ends"]
            assert sum(expected["ends"]) == 2
            np.testing.assert_array_equal(
                np.array(played[i]["observations"]), np.array(expected["observations"])
            )
            np.testing.assert_allclose(played[i]["rewards"], expected["rewards"], rtol=1e-6)
            assert played[i]["scores"] == expected["scores"]
    finally:
        batch.close()


@pytest.mark.parametrize("engine", ENGINES)
def test_ppo_on_a_batch_trains_the_budget_counts_every_world_and_closes_its_worlds(
    env_of, engine: str
) -> None:
    env = env_of("stand-up", "arch_chain", simulator=engine)
    learner = PPOLearner(PPOOptions(n_envs=4, n_steps=64, batch_size=32, n_epochs=2))
    made: list[BatchedEnv] = []
    make_batch = learner.training_env

    def keep(given: Any) -> Any:
        batch = make_batch(given)
        made.append(batch)
        return batch

    learner.training_env = keep  # type: ignore[method-assign]
    steps = 256
    trained = learner.train(env, steps=steps, seed=3, keep_checkpoint=True)
    [batch] = made
    assert isinstance(batch, BatchedEnv) and batch.num_envs == 4 and batch.worlds[0] is env
    assert trained.train_steps == steps
    # every world's physics steps are the job's: frame_skip per env step, all worlds
    assert env.sim_steps == steps * env.options.frame_skip
    assert env.sim.connected
    assert [world.sim.connected for world in batch.worlds[1:]] == [False] * 3
    # the training episodes of all worlds are the curve: 256 steps of 32-step episodes
    assert len(trained.curve) == steps // 32
    assert [point["steps"] for point in trained.curve] == sorted(
        point["steps"] for point in trained.curve
    )
    # its checkpoint loads into a learner of one env (n_envs is not in the weights)
    single = PPOLearner(PPOOptions())
    model = single.load_checkpoint(env, trained.checkpoint or b"", steps=steps, seed=3)
    assert model.num_timesteps == steps and model.n_envs == 1
    action = trained.policy(env.reset(seed=5)[0])
    assert action.shape == env.action_space.shape
    env.close()


def test_training_on_a_batch_checks_for_cancellation_every_64_steps(env_of) -> None:
    """``check`` (a cancelled job's way out) runs once every 64 env steps, though a batch
    of 3 worlds steps 3 at a time and seldom lands on a multiple of 64."""
    env = env_of("stand-up", "arch_chain", simulator="mujoco")
    checked: list[int] = []
    learner = PPOLearner(PPOOptions(n_envs=3, n_steps=96, batch_size=48, n_epochs=1))
    try:
        trained = learner.train(env, steps=384, seed=0, check=lambda: checked.append(1))
    finally:
        env.close()
    assert trained.train_steps == 384
    assert len(checked) == 384 // 64


def test_n_envs_is_bounded() -> None:
    assert PPOOptions(n_envs=MAX_BATCH_WORLDS).n_envs == MAX_BATCH_WORLDS
    with pytest.raises(ValidationError, match="n_envs"):
        PPOOptions(n_envs=MAX_BATCH_WORLDS + 1)
    with pytest.raises(ValidationError, match="n_envs"):
        PPOOptions(n_envs=0)
    assert "n_envs" not in PPOOptions(n_envs=8).hyperparameters()


@pytest.mark.e2e
@pytest.mark.parametrize("engine", ENGINES)
def test_a_ppo_study_on_a_batch_runs_end_to_end(server, tmp_path: Path, engine: str) -> None:
    """examples/one-design.yaml's arch, PPO on 4 worlds, with a real adserver and
    adworker: the trials complete, their curve is the contract's, their checkpoint
    (``task.transfer: nearest`` keeps one) is a checkpoint of the steps trained."""
    body = yaml.safe_load((EXAMPLES / "stand-up.yaml").read_text())
    steps = 512
    body.update(name=f"batched-{engine}", max_trials=2, proposer={"name": "random", "seed": 0})
    body["task"].update(
        learner="ppo",
        train_steps=steps,
        eval_episodes=2,
        simulator=engine,
        transfer="nearest",
        options={"learner_kwargs": {"n_envs": 4}},
    )
    with Client(server.url) as client:
        study = client.create_study(body)
        worker = WorkerProcess(server, tmp_path, "batched", "--no-render", "--max-jobs", "2")
        try:
            assert worker.wait() == 0, worker.log()
        finally:
            worker.stop()
        trials = client.trials(study.id)
        assert [t.state for t in trials] == ["complete"] * 2, worker.log()
        # the second starts from the first one's batch-trained checkpoint, for the warm
        # budget: a transfer across designs on the batch
        first, second = sorted(trials, key=lambda t: t.number)
        assert "transfer_steps" not in first.metrics
        budgets = [steps, second.metrics["transfer_steps"]]
        assert budgets[1] < steps
        for trial, budget in zip((first, second), budgets, strict=True):
            assert trial.metrics["train_steps"] == budget
            # every world's physics steps: training's (frame_skip 12) and evaluation's
            assert trial.metrics["sim_steps"] > budget * 12
            curve = client.trial_curve(trial)
            assert curve.learner == "ppo" and curve.train_steps == budget
            assert len(curve.evaluation) == 2
            assert curve.train and all(0 < point.steps <= budget for point in curve.train)
            checkpoint = client.get_artifact(trial, CHECKPOINT_ARTIFACT)
            assert checkpoint.startswith(b"PK")
