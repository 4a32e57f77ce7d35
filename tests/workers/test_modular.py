"""Issue 38, the policy side of a shared controller (real SB3 PPO on real PyBullet
envs): the modular observation regroups an env's flat observation per joint and
globally, models of designs of different trees and joint counts have the same
weights (names, shapes and, for a seed, initial values, in any process), weights
trained on one design drive another, and a ``Shared`` start returns its update and the
weights it started from, falling back to the initial weights, with the reason, when
the given ones do not fit."""

from __future__ import annotations

import hashlib
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from adworker import modular
from adworker.designs import HALF_PI, tree_design
from adworker.learners import PPOLearner, SACLearner, evaluate_policy
from adworker.modular_arrays import ArrayForward
from adworker.shared_weights import SharedWeightsError, Weights, decode, encode
from adworker.starts import Shared

pytestmark = pytest.mark.slow

STEPS = 256
FORK_EDGES = [("a", "b"), ("b", "c"), ("b", "d"), ("b", "e")]


def fork():
    """b carries three limbs (a tree of examples/multi-structure.yaml): 4 joints."""
    angles = {"b": (HALF_PI, HALF_PI), "c": (HALF_PI, 0.3), "d": (0.4, 1.0), "e": (1.2, 2.0)}
    return tree_design(FORK_EDGES, angles)


def modular_model(env) -> object:
    return PPOLearner().make_model(
        env,
        steps=STEPS,
        seed=0,
        policy=modular.ModularPolicy,
        policy_kwargs=modular.policy_kwargs(env),
    )


def digest(weights: Weights) -> str:
    hashed = hashlib.sha256()
    for name in sorted(weights):
        hashed.update(name.encode())
        hashed.update(np.ascontiguousarray(weights[name], dtype=np.float32).tobytes())
    return hashed.hexdigest()


def same(first: Weights, second: Weights) -> bool:
    return set(first) == set(second) and all(
        np.array_equal(first[name], second[name]) for name in first
    )


def test_the_modular_observation_is_the_flat_one_regrouped_per_joint(env_of) -> None:
    chain, tree = env_of("lift-highest", "arch_chain"), env_of("lift-highest", fork())
    chain_layout, layout = modular.layout_of(chain), modular.layout_of(tree)
    assert chain_layout.parents == (0, 1)
    assert layout.parents == (0, 1, 1, 1)  # a-b from the root, then b's three limbs
    assert (layout.joint_size, layout.global_size) == (
        chain_layout.joint_size,
        chain_layout.global_size,
    )

    observation, _ = tree.reset(seed=0)
    for _ in range(3):
        observation, *_ = tree.step(np.array([0.8, -0.5, 0.5, -0.8], dtype=np.float32))
    joints, overall = layout.blocks(observation)
    snapshot = tree.snapshot()
    assert joints.shape == (4, layout.joint_size) and overall.shape == (layout.global_size,)
    np.testing.assert_allclose(joints[:, 0], observation[:4])  # positions
    np.testing.assert_allclose(joints[:, 1], observation[4:8])  # velocities
    children = [tree.robot.link_index(joint.child) for joint in tree.robot.joints]
    np.testing.assert_allclose(joints[:, 2], [snapshot.centre_z[k] for k in children], rtol=1e-6)
    assert list(joints[:, 3]) == [float(snapshot.touching[k]) for k in children]
    depth = joints[:, len(modular.JOINT_DYNAMIC) + modular.JOINT_STATIC.index("depth")]
    np.testing.assert_allclose(depth, [0.25, 0.5, 0.5, 0.5])
    base = snapshot.poses[0][0][2]
    assert overall[modular.GLOBAL_FIXED.index("base_height")] == pytest.approx(base, rel=1e-6)


def test_a_task_with_extras_and_a_fixed_base_has_them_in_its_global_block(env_of) -> None:
    env = env_of("diagonal-gesture", "crossed_chain")
    layout = modular.layout_of(env)
    observation, _ = env.reset(seed=0)
    joints, overall = layout.blocks(observation)
    assert layout.global_size == len(modular.GLOBAL_FIXED) + 3
    np.testing.assert_allclose(overall[-3:], observation[-3:])  # the distal link's axis
    assert not overall[: modular.GLOBAL_FIXED.index("root_height")].any()  # no free base
    assert not joints[:, 2:4].any()  # nor heights and contacts


def test_designs_of_different_trees_have_the_same_weights(env_of) -> None:
    chain = modular_model(env_of("lift-highest", "arch_chain"))
    tree = modular_model(env_of("lift-highest", fork()))
    chain_weights, tree_weights = modular.shared_weights_of(chain), modular.shared_weights_of(tree)
    shapes = {name: array.shape for name, array in chain_weights.items()}
    assert shapes == {name: array.shape for name, array in tree_weights.items()}
    assert shapes["log_std"] == (1,)  # one log-std shared by all joints

    assert same(modular.initial_weights(chain, 5), modular.initial_weights(tree, 5))
    assert not same(modular.initial_weights(chain, 5), modular.initial_weights(chain, 6))
    # The format's own names and values: they travel as a file.
    assert same(decode(encode(chain_weights)), chain_weights)


def test_the_initial_weights_are_the_same_in_another_process(env_of, tmp_path: Path) -> None:
    here = digest(modular.initial_weights(modular_model(env_of("lift-highest", "arch_chain")), 7))
    probe = f"""
import hashlib, sys
import numpy as np
from adclient.plugins import catalogue
from adclient.urdf import design_to_urdf
from adworker import modular
from adworker.modular_arrays import ArrayForward
from adworker.designs import HALF_PI, tree_design
from adworker.learners import PPOLearner

design = tree_design({FORK_EDGES!r}, {{name: (HALF_PI, 0.5) for name in "bcde"}})
path = sys.argv[1]
open(path, "w").write(design_to_urdf(design, robot_name="robot"))
spec = catalogue().task("lift-highest")
env = spec.load_factory()(design=design, urdf_path=path, options=spec.options(), render_mode=None)
model = PPOLearner().make_model(env, steps=256, seed=3, policy=modular.ModularPolicy,
                                policy_kwargs=modular.policy_kwargs(env))
weights = modular.initial_weights(model, 7)
hashed = hashlib.sha256()
for name in sorted(weights):
    hashed.update(name.encode())
    hashed.update(np.ascontiguousarray(weights[name], dtype=np.float32).tobytes())
print(hashed.hexdigest())
"""
    done = subprocess.run(
        [sys.executable, "-c", probe, str(tmp_path / "other.urdf")],
        capture_output=True,
        text=True,
        check=True,
    )
    assert done.stdout.split()[-1] == here


def test_a_shared_start_returns_its_update_and_a_policy_of_the_raw_env(env_of) -> None:
    env = env_of("lift-highest", "arch_chain")
    learner = PPOLearner()
    result = learner.train(env, steps=20_000, seed=0, start=Shared(None, steps=STEPS, seed=3))

    assert learner.warm_problem is None and not result.warm_started
    assert STEPS <= result.train_steps < 20_000  # the start's steps, not the budget
    assert result.shared is not None and result.shared_start is not None
    assert same(result.shared_start, modular.initial_weights(modular_model(env), 3))
    moved = [
        name
        for name in result.shared
        if not np.array_equal(result.shared[name], result.shared_start[name])
    ]
    assert "action_net.linear.weight" in moved and "value_net.weight" in moved
    assert result.info["policy"] == "modular"

    plain = env_of("lift-highest", "arch_chain")
    episode = evaluate_policy(plain, result.policy, [0])[0]
    assert len(episode.metric) == plain.episode_steps
    assert result.policy(plain.reset(seed=1)[0]).shape == (2,)


def test_weights_trained_on_one_tree_drive_another(env_of) -> None:
    source = PPOLearner().train(
        env_of("lift-highest", "arch_chain"), steps=STEPS, seed=0, start=Shared(None, STEPS, 3)
    )
    assert source.shared is not None

    tree = env_of("lift-highest", fork())
    learner = PPOLearner()
    start = Shared(source.shared, steps=128, seed=3, version=4)
    result = learner.train(tree, steps=20_000, seed=1, start=start)
    assert learner.warm_problem is None and result.warm_started
    assert result.shared_start is not None and same(result.shared_start, source.shared)
    assert result.policy(tree.reset(seed=0)[0]).shape == (4,)

    # As loaded, before any training: the other design's weights, acting with 4 joints.
    model = modular_model(tree)
    modular.load_shared(model, source.shared)
    assert same(modular.shared_weights_of(model), source.shared)
    action, _ = model.predict(tree.reset(seed=0)[0], deterministic=True)
    assert action.shape == (4,)


def other_task_weights(env_of) -> Weights:
    """Initial weights of a task with extras (diagonal-gesture's 3): another global size."""
    return modular.initial_weights(modular_model(env_of("diagonal-gesture", "crossed_chain")), 3)


@pytest.mark.parametrize(
    ("spoil", "named"),
    [
        (lambda weights, env_of: {k: v for k, v in weights.items() if k != "log_std"}, "log_std"),
        (lambda weights, env_of: {**weights, "extra.weight": weights["log_std"]}, "extra.weight"),
        (lambda weights, env_of: other_task_weights(env_of), "joint_in.weight"),
    ],
    ids=["missing", "unknown", "another-task"],
)
def test_weights_that_do_not_fit_fall_back_to_the_initial_ones(env_of, spoil, named) -> None:
    env = env_of("lift-highest", "arch_chain")
    good = modular.initial_weights(modular_model(env), 11)
    learner = PPOLearner()
    start = Shared(spoil(good, env_of), steps=128, seed=3, version=2)
    result = learner.train(env, steps=512, seed=0, start=start)

    assert learner.warm_problem is not None
    assert "version 2" in learner.warm_problem and named in learner.warm_problem
    assert not result.warm_started
    assert result.shared_start is not None
    assert same(result.shared_start, modular.initial_weights(modular_model(env), 3))
    # from the initial weights, the from-scratch budget (not the warm one)
    assert result.train_steps >= 512 and result.shared is not None
    with pytest.raises(SharedWeightsError, match=named.replace(".", r"\.")):
        modular.load_shared(modular_model(env), start.weights or {})


def test_a_corrupt_file_is_refused_before_it_reaches_a_model() -> None:
    with pytest.raises(SharedWeightsError, match="not shared-controller weights"):
        decode(b"PK\x03\x04 not a zip")


def test_a_learner_without_a_modular_policy_trains_from_scratch_and_says_why(env_of) -> None:
    learner = SACLearner()
    result = learner.train(
        env_of("stand-up", "arch_chain"), steps=64, seed=0, start=Shared(None, 32, 3)
    )
    assert learner.warm_problem is not None and "sac" in learner.warm_problem
    assert result.shared is None and result.shared_start is None
    assert result.train_steps == 64


@pytest.mark.parametrize(
    ("task", "design"),
    [
        ("lift-highest", "arch_chain"),  # free base, contacts
        ("lift-highest", "fork"),  # four joints, a limb carrying three
        ("diagonal-gesture", "crossed_chain"),  # fixed base, task extras
        ("walk-forward", "arch_chain"),  # the gait clock
    ],
)
def test_acting_in_numpy_gives_torch_s_numbers(env_of, task: str, design: str) -> None:
    """A step's action mean, value and log-probability, and an evaluation's action, from
    the NumPy forward equal torch's (the path training's batches take) within float32
    rounding, on observations of a rolled-out env and on a batch of them, after the
    weights moved away from their initial values."""
    import torch

    env = env_of(task, fork() if design == "fork" else design)
    model = modular_model(env)
    policy = model.policy
    with torch.no_grad():  # weights away from the initial ones, so every layer matters
        for parameter in policy.parameters():
            parameter.add_(0.3 * torch.randn_like(parameter))
    observations = [env.reset(seed=0)[0]]
    for _ in range(20):
        observations.append(env.step(env.action_space.sample())[0])
    batch = torch.as_tensor(np.stack(observations), dtype=torch.float32)

    means, values = ArrayForward(policy)(batch.numpy())
    latent = policy.mlp_extractor(batch)[0]
    torch_means = policy._get_action_dist_from_latent(latent).distribution.loc
    torch_values = policy.predict_values(batch)
    np.testing.assert_allclose(means, torch_means.detach().numpy(), rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(values, torch_values.detach().numpy(), rtol=1e-4, atol=1e-5)

    with torch.no_grad():
        torch.manual_seed(11)
        actions, step_values, log_prob = policy(batch[:1])
    torch.manual_seed(11)
    expected_actions, expected_values, expected_log_prob = policy(batch[:1])  # with grad: torch
    np.testing.assert_allclose(actions, expected_actions.detach(), rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(step_values, expected_values.detach(), rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(log_prob, expected_log_prob.detach(), rtol=1e-4, atol=1e-4)

    with torch.no_grad():
        acted = policy._predict(batch[:3], deterministic=True)
    np.testing.assert_allclose(acted, torch_means[:3].detach().numpy(), rtol=1e-4, atol=1e-5)


def test_a_rollout_acts_through_numpy_and_training_through_torch(env_of, monkeypatch) -> None:
    """Every rollout step and an evaluation's action go through the NumPy forward; the
    torch tree network runs with gradients for training's batches, and without them only
    for the values SB3 bootstraps from (``predict_values``: a rollout's last, a truncated
    episode's)."""
    import torch

    env = env_of("lift-highest", "arch_chain")
    model = modular_model(env)
    arrays: list[int] = []
    numpy_forward = ArrayForward.__call__

    def counted(self, observation):
        arrays.append(len(observation))
        return numpy_forward(self, observation)

    monkeypatch.setattr(ArrayForward, "__call__", counted)
    tree: list[bool] = []
    model.policy.mlp_extractor.tree.register_forward_hook(
        lambda *_: tree.append(torch.is_grad_enabled())
    )
    model.learn(total_timesteps=STEPS)
    assert model.num_timesteps >= STEPS and len(arrays) == model.num_timesteps  # every step
    assert tree.count(True) > 0  # training's batches
    # without gradients only the values SB3 bootstraps from (a rollout's last, a
    # truncated episode's), never a step's
    assert 0 < tree.count(False) < model.num_timesteps // 10, tree.count(False)

    arrays.clear()
    tree.clear()
    action, _ = model.predict(env.reset(seed=0)[0], deterministic=True)
    assert action.shape == (2,) and arrays == [1] and tree == []


ACTOR = {"log_std", "action_net.linear.weight", "action_net.linear.bias"}
"""The modular policy's arrays of the actor alone (and head 0 of the stacked tree ones)."""
CRITIC = {"value_net.weight", "value_net.bias", "mlp_extractor.pool.weight"}
CRITIC |= {"mlp_extractor.pool.bias"}


@pytest.mark.parametrize("carries", ["critic", "all"])
def test_a_version_carries_its_critic_or_all_of_it(env_of, carries) -> None:
    """``carries: critic``: the design's actor (the tree network's actor head, action
    head and log-std) starts from the study's initial weights, its critic from the
    version; ``all``: everything from the version. Either way the start it reports is
    the version it loaded. Every array of the version differs from the initial one (a
    seed's initial biases and log-std are all zero), so a part left out shows."""
    env = env_of("lift-highest", "arch_chain")
    initial = modular.initial_weights(modular_model(env), 3)
    version = {
        name: value + 1.0 for name, value in modular.initial_weights(modular_model(env), 11).items()
    }
    start = Shared(version, steps=0, seed=3, version=5, carries=carries)
    result = PPOLearner().train(env, steps=512, seed=0, start=start)

    assert result.train_steps == 0 and result.warm_started
    assert result.shared_start is not None and same(result.shared_start, version)
    assert result.shared is not None
    stacked = {name for name in result.shared if name.startswith("mlp_extractor.tree.")}
    assert set(result.shared) == ACTOR | CRITIC | stacked and len(stacked) == 12
    if carries == "all":
        assert same(result.shared, version)
        return
    for name, value in result.shared.items():
        if name in stacked:
            assert np.array_equal(value[0], initial[name][0]), name
            assert np.array_equal(value[1], version[name][1]), name
        else:
            expected = initial if name in ACTOR else version
            assert np.array_equal(value, expected[name]), name
