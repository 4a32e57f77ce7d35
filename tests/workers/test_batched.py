"""Batched worlds and PPO on the batch (issue 59), real engines both: world i of a batch
plays the same episodes as one env seeded as it is and given the same actions; the
``ppo`` learner's ``n_envs`` trains on a batch for the same budget, counts every world's
physics steps and closes the worlds it built; the lean ``ppo-batch`` learner's parts
(GAE, its NumPy policy, its update) and its contracts (budget, checkpoint, resume, warm
start, pause); and a real adserver and adworker run a study with each end to end, on
both engines, its curve, checkpoint and warm start valid."""

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


BATCHED_LEARNERS = {
    "ppo": {"n_envs": 4},
    "ppo-batch": {"n_envs": 4, "unroll": 16, "n_minibatches": 2},
}
"""The learners that train on a batch, each with 4 worlds: SB3's PPO and the lean one."""


@pytest.mark.e2e
@pytest.mark.parametrize("learner", list(BATCHED_LEARNERS))
@pytest.mark.parametrize("engine", ENGINES)
def test_a_ppo_study_on_a_batch_runs_end_to_end(
    server, tmp_path: Path, engine: str, learner: str
) -> None:
    """examples/stand-up.yaml, each batched learner on 4 worlds, on each engine, with a
    real adserver and adworker: the trials complete, their curve is the contract's, their
    checkpoint (``task.transfer: nearest`` keeps one) is a checkpoint of the steps
    trained, and the second design warm-starts from the first's."""
    body = yaml.safe_load((EXAMPLES / "stand-up.yaml").read_text())
    steps = 512  # the warm start's budget, a quarter of it, ends an episode of each world
    body.update(
        name=f"batched-{learner}-{engine}", max_trials=2, proposer={"name": "random", "seed": 0}
    )
    body["task"].update(
        learner=learner,
        train_steps=steps,
        eval_episodes=2,
        simulator=engine,
        transfer="nearest",
        options={"learner_kwargs": BATCHED_LEARNERS[learner]},
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
            assert curve.learner == learner and curve.train_steps == budget
            assert len(curve.evaluation) == 2
            assert curve.train and all(0 < point.steps <= budget for point in curve.train)
            checkpoint = client.get_artifact(trial, CHECKPOINT_ARTIFACT)
            assert checkpoint.startswith(b"PK")


# ---------------------------------------------------------------------- ppo-batch


def test_the_lean_ppos_gae_is_the_per_world_recursion() -> None:
    """Rollout.gae (all worlds at once) against the textbook recursion, world by world,
    episodes ending at random steps."""
    from adworker.batch_ppo import Rollout

    rng = np.random.default_rng(0)
    unroll, worlds, gamma, lam = 9, 5, 0.95, 0.9
    rollout = Rollout(unroll, worlds, 3, 2)
    rollout.rewards[:] = rng.normal(size=(unroll, worlds))
    rollout.values[:] = rng.normal(size=(unroll, worlds))
    rollout.dones[:] = rng.uniform(size=(unroll, worlds)) < 0.3
    last = rng.normal(size=worlds).astype(np.float32)
    length = 7  # a shorter last rollout uses only its first steps
    found = rollout.gae(last, length, gamma, lam).copy()
    for i in range(worlds):
        expected, running = np.zeros(length), 0.0
        for t in reversed(range(length)):
            following = last[i] if t == length - 1 else rollout.values[t + 1, i]
            alive = 0.0 if rollout.dones[t, i] else 1.0
            delta = rollout.rewards[t, i] + gamma * following * alive - rollout.values[t, i]
            running = delta + gamma * lam * alive * running
            expected[t] = running
        np.testing.assert_allclose(found[:, i], expected, rtol=1e-5, atol=1e-6)


def test_the_lean_ppos_numpy_policy_is_its_torch_networks() -> None:
    """The rollout's NumPy forward (once per batch step) is the torch actor and critic
    the update trains, and its Gaussian log-probability is torch's."""
    import torch

    from adworker.batch_ppo import Networks, _log_prob_of_noise

    networks = Networks(7, 3, [16, 8], -0.5, seed=2)
    with torch.no_grad():
        networks.log_std.add_(torch.tensor([0.1, -0.2, 0.3]))
        for parameter in networks.actor.parameters():
            parameter.add_(0.1)  # past the small initial head: a mean not near 0
    networks.refresh()
    observations = np.random.default_rng(1).normal(size=(11, 7)).astype(np.float32)
    with torch.no_grad():
        mean = networks.actor(torch.as_tensor(observations)).numpy()
        value = networks.critic(torch.as_tensor(observations))[:, 0].numpy()
    np.testing.assert_allclose(networks.mean(observations), mean, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(networks.value(observations), value, rtol=1e-5, atol=1e-6)
    noise = np.random.default_rng(3).normal(size=(11, 3)).astype(np.float32)
    actions = mean + networks.std * noise
    gaussian = torch.distributions.Normal(torch.as_tensor(mean), networks.log_std.exp().detach())
    expected = gaussian.log_prob(torch.as_tensor(actions)).sum(-1).numpy()
    np.testing.assert_allclose(_log_prob_of_noise(noise, networks.std), expected, rtol=1e-5)


def test_the_lean_ppos_update_moves_the_policy_towards_advantageous_actions() -> None:
    """One update on a rollout whose advantage is the sign of the first joint's action
    (or its opposite): that joint's mean moves that way, more than the other's."""
    from adclient.builtin_learners import BatchPPOOptions
    from adworker.batch_ppo import BatchPPOLearner, Networks, Rollout, _torch_generator

    learner = BatchPPOLearner(BatchPPOOptions(n_envs=8, unroll=16, n_epochs=4))
    for sign in (1.0, -1.0):
        networks = Networks(4, 2, [32, 32], 0.0, seed=0)
        optimiser = learner.optimiser(networks)
        rng = np.random.default_rng(0)
        rollout = Rollout(16, 8, 4, 2)
        rollout.observations[:] = rng.normal(size=rollout.observations.shape)
        flat = rollout.observations.reshape(-1, 4)
        noise = rng.standard_normal((16 * 8, 2)).astype(np.float32)
        rollout.actions[:] = (networks.mean(flat) + networks.std * noise).reshape(16, 8, 2)
        rollout.log_probs[:] = (-0.5 * noise**2 - 0.5 * np.log(2 * np.pi)).sum(-1).reshape(16, 8)
        advantages = sign * np.sign(rollout.actions[..., 0]).astype(np.float32)
        before = networks.mean(flat)
        learner._update(networks, optimiser, rollout, advantages, 16, _torch_generator(0))
        networks.refresh()
        moved = (networks.mean(flat) - before).mean(axis=0)
        assert sign * moved[0] > 0.02 and abs(moved[1]) < abs(moved[0]), (sign, moved)


@pytest.mark.parametrize("engine", ENGINES)
def test_ppo_batch_trains_on_a_batch_and_keeps_the_learners_contracts(env_of, engine: str) -> None:
    """``ppo-batch`` trains the budget on 4 worlds (every world's physics steps the job's,
    the worlds it built closed, every world's episodes in its curve); its checkpoint
    resumes a paused trial to the budget, warm-starts a design, and one of other networks
    is refused by name (the design then trains from scratch); a pruner's pause carries a
    checkpoint of the step it stopped at."""
    from adclient.builtin_learners import BatchPPOOptions
    from adworker.batch_ppo import BatchPPOLearner
    from adworker.runner import Pruned
    from adworker.starts import Reporting, Resume, Warm

    env = env_of("stand-up", "arch_chain", simulator=engine)
    options = BatchPPOOptions(n_envs=4, unroll=16, n_minibatches=2, n_epochs=2)
    steps = 256
    learner = BatchPPOLearner(options)
    try:
        trained = learner.train(env, steps=steps, seed=3, keep_checkpoint=True)
        assert trained.train_steps == steps and trained.info["algorithm"] == "ppo-batch"
        assert env.sim_steps == steps * env.options.frame_skip
        assert env.sim.connected
        assert len(trained.curve) == steps // 32
        assert all(0 < point["steps"] <= steps for point in trained.curve)
        assert trained.checkpoint is not None and trained.checkpoint.startswith(b"PK")
        first = trained.policy(env.reset(seed=5)[0])
        assert first.shape == env.action_space.shape and np.all(np.abs(first) <= 1)

        # paused at 128 by a pruner: the pause carries a checkpoint of 128 steps
        def pause(step: int, value: float) -> None:
            raise Pruned(step, value, pause=True)

        reporting = Reporting(every=128, evaluate=lambda policy: 0.5, report=pause)
        with pytest.raises(Pruned) as paused:
            BatchPPOLearner(options).train(env, steps=steps, seed=3, reporting=reporting)
        assert paused.value.step == 128 and paused.value.checkpoint is not None
        reports: list[int] = []
        reporting = Reporting(
            every=128, evaluate=lambda policy: 0.5, report=lambda s, v: reports.append(s)
        )
        resumed = BatchPPOLearner(options).train(
            env, steps=steps, seed=3, start=Resume(paused.value.checkpoint), reporting=reporting
        )
        assert resumed.train_steps == steps and reports == []  # 256 is the end, not a report

        warm = BatchPPOLearner(options)
        started = warm.train(env, steps=steps, seed=4, start=Warm(trained.checkpoint, 64))
        assert warm.warm_problem is None and started.warm_started
        assert started.train_steps == 64

        other = BatchPPOLearner(BatchPPOOptions(n_envs=2, unroll=16, net_arch=[32]))
        scratch = other.train(env, steps=64, seed=4, start=Warm(trained.checkpoint, 32))
        assert not scratch.warm_started and scratch.train_steps == 64
        assert other.warm_problem is not None and "net_arch" in other.warm_problem
    finally:
        env.close()


def test_ppo_batch_options_are_bounded_and_their_cost_refused_by_name() -> None:
    from adclient.builtin_learners import BatchPPOOptions

    with pytest.raises(ValidationError, match="n_envs"):
        BatchPPOOptions(n_envs=MAX_BATCH_WORLDS + 1)
    with pytest.raises(ValidationError, match="unroll"):
        BatchPPOOptions(unroll=0)
    assert BatchPPOOptions().budget_problems(None) == []
    costly = BatchPPOOptions(n_envs=1, unroll=1, n_minibatches=1, n_epochs=100)
    [problem] = costly.budget_problems(1_000_000)
    assert "100,000,000 gradient updates" in problem and "n_epochs 100" in problem, problem
    # updates per sample at the defaults: 16 a rollout of 512, against ppo's 40
    assert BatchPPOOptions().work(12288).updates == 24 * 16
    assert PPOOptions().work(12288).updates == 24 * 40
