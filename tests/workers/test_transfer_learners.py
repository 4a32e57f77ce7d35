"""Issue 27, the learners' side of transfer, for each built-in RL learner (real SB3 on
real PyBullet envs): a learner returns its final state when asked, a warm-started one
trains its warm budget from that state (its parameters stay near the source's, far from
a fresh start's; an off-policy learner keeps the source's replay buffer), and a state
that does not fit the design (another tree) or does not load is refused with the reason,
the design then trained from scratch."""

from __future__ import annotations

import io
import zipfile

import numpy as np
import pytest

from adworker.designs import HALF_PI, arch_chain, tree_design
from adworker.learners import (
    MODEL_MEMBER,
    REPLAY_MEMBER,
    StableBaselinesLearner,
    TrainResult,
    WarmStart,
)

pytestmark = pytest.mark.slow

LEARNERS = ["ppo", "sac", "td3", "ddpg"]
SOURCE_STEPS, WARM_STEPS = 128, 32


def learner_of(name: str) -> StableBaselinesLearner:
    from adclient.plugins import catalogue

    learner = catalogue().learner(name).load_factory()(None)
    assert isinstance(learner, StableBaselinesLearner)
    learner.keep_checkpoint = True
    return learner


def parameters(result: TrainResult) -> np.ndarray:
    """The policy's parameters (actor and critics) in the checkpoint, as one vector."""
    import torch

    assert result.checkpoint is not None
    with zipfile.ZipFile(io.BytesIO(result.checkpoint)) as outer:
        saved = outer.read(MODEL_MEMBER)
    with zipfile.ZipFile(io.BytesIO(saved)) as model:
        state = torch.load(io.BytesIO(model.read("policy.pth")), weights_only=True)
    return np.concatenate([value.numpy().ravel() for value in state.values()])


def replay_size(result: TrainResult) -> int | None:
    import pickle

    assert result.checkpoint is not None
    with zipfile.ZipFile(io.BytesIO(result.checkpoint)) as archive:
        if REPLAY_MEMBER not in archive.namelist():
            return None
        buffer = pickle.loads(archive.read(REPLAY_MEMBER))
    return int(buffer.buffer_size if buffer.full else buffer.pos)


@pytest.mark.parametrize("name", LEARNERS)
def test_a_warm_started_learner_trains_on_from_the_source_state(name: str, env_of) -> None:
    near = arch_chain(length=0.45)
    source = learner_of(name).train(env_of("stand-up", "arch_chain"), steps=SOURCE_STEPS, seed=0)
    assert source.checkpoint is not None and not source.warm_started

    warm_learner = learner_of(name)
    warm_learner.warm_start = WarmStart(source.checkpoint, WARM_STEPS)
    warm = warm_learner.train(env_of("stand-up", near), steps=SOURCE_STEPS, seed=1)
    fresh = learner_of(name).train(env_of("stand-up", near), steps=WARM_STEPS, seed=1)

    assert warm.warm_started and warm_learner.warm_problem is None
    assert WARM_STEPS <= warm.train_steps < SOURCE_STEPS  # PPO rounds up to its rollout
    moved = np.linalg.norm(parameters(warm) - parameters(source))
    apart = np.linalg.norm(parameters(fresh) - parameters(source))
    assert moved < 0.5 * apart, (moved, apart)
    if name != "ppo":  # the source's transitions, then the design's own
        assert replay_size(warm) == SOURCE_STEPS + warm.train_steps


@pytest.mark.parametrize("name", ["ppo", "sac"])
def test_a_state_that_does_not_fit_is_refused_and_the_design_trains_from_scratch(
    name: str, env_of
) -> None:
    source = learner_of(name).train(env_of("stand-up", "arch_chain"), steps=SOURCE_STEPS, seed=0)
    assert source.checkpoint is not None
    star = tree_design(
        [("a", "b"), ("a", "c"), ("a", "d")],
        {child: (HALF_PI, HALF_PI) for child in "bcd"},
    )
    for checkpoint, reason in ((source.checkpoint, "space"), (b"PK\0\0 not a zip", "zip")):
        learner = learner_of(name)
        learner.warm_start = WarmStart(checkpoint, WARM_STEPS)
        result = learner.train(env_of("lift-highest", star), steps=64, seed=0)
        assert not result.warm_started and result.train_steps >= 64
        assert learner.warm_problem is not None and reason in learner.warm_problem.lower()
