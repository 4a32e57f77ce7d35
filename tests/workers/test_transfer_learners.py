"""Issue 27, the learners' side of transfer, for each built-in RL learner (real SB3 on
real PyBullet envs): a learner returns its final state when asked, a warm-started one
trains its warm budget from that state (its parameters stay near the source's, far from
a fresh start's; an off-policy learner keeps the source's replay buffer), and a state
that does not fit the design (another tree) or does not load is refused with the reason,
the design then trained from scratch. A checkpoint whose unpickling would run code is
refused unread, warm start or resume (issue 36)."""

from __future__ import annotations

import io
import pickle
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from adworker.checkpoints import PARAMETERS_MEMBER, REPLAY_MEMBER
from adworker.designs import HALF_PI, arch_chain, tree_design
from adworker.learners import StableBaselinesLearner, TrainResult
from adworker.starts import Resume, Warm

pytestmark = pytest.mark.slow

LEARNERS = ["ppo", "sac", "td3", "ddpg"]
SOURCE_STEPS, WARM_STEPS = 128, 32


def learner_of(name: str) -> StableBaselinesLearner:
    from adclient.plugins import catalogue

    learner = catalogue().learner(name).load_factory()(None)
    assert isinstance(learner, StableBaselinesLearner)
    return learner


def parameters(result: TrainResult) -> np.ndarray:
    """The policy's parameters (actor and critics) in the checkpoint, as one vector."""
    import torch

    assert result.checkpoint is not None
    with zipfile.ZipFile(io.BytesIO(result.checkpoint)) as archive:
        saved = archive.read(PARAMETERS_MEMBER)
    state = torch.load(io.BytesIO(saved), weights_only=True)["state_dicts"]["policy"]
    return np.concatenate([value.numpy().ravel() for value in state.values()])


def replay_size(result: TrainResult) -> int | None:
    assert result.checkpoint is not None
    with zipfile.ZipFile(io.BytesIO(result.checkpoint)) as archive:
        if REPLAY_MEMBER not in archive.namelist():
            return None
        with np.load(io.BytesIO(archive.read(REPLAY_MEMBER)), allow_pickle=False) as buffer:
            return len(buffer["observations"])


@pytest.mark.parametrize("name", LEARNERS)
def test_a_warm_started_learner_trains_on_from_the_source_state(name: str, env_of) -> None:
    near = arch_chain(length=0.45)
    source = learner_of(name).train(
        env_of("stand-up", "arch_chain"), steps=SOURCE_STEPS, seed=0, keep_checkpoint=True
    )
    assert source.checkpoint is not None and not source.warm_started

    warm_learner = learner_of(name)
    start = Warm(source.checkpoint, WARM_STEPS)
    warm = warm_learner.train(
        env_of("stand-up", near), steps=SOURCE_STEPS, seed=1, start=start, keep_checkpoint=True
    )
    fresh = learner_of(name).train(
        env_of("stand-up", near), steps=WARM_STEPS, seed=1, keep_checkpoint=True
    )

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
    source = learner_of(name).train(
        env_of("stand-up", "arch_chain"), steps=SOURCE_STEPS, seed=0, keep_checkpoint=True
    )
    assert source.checkpoint is not None
    star = tree_design(
        [("a", "b"), ("a", "c"), ("a", "d")],
        {child: (HALF_PI, HALF_PI) for child in "bcd"},
    )
    for checkpoint, reason in ((source.checkpoint, "space"), (b"PK\0\0 not a zip", "zip")):
        learner = learner_of(name)
        start = Warm(checkpoint, WARM_STEPS)
        result = learner.train(env_of("lift-highest", star), steps=64, seed=0, start=start)
        assert not result.warm_started and result.train_steps >= 64
        assert learner.warm_problem is not None and reason in learner.warm_problem.lower()


class WritesFile:
    """Unpickled, it opens ``path`` for writing: the file then exists."""

    def __init__(self, path: Path) -> None:
        self.path = str(path)

    def __reduce__(self) -> tuple[Any, tuple[str, str]]:
        return (open, (self.path, "w"))


def with_member(checkpoint: bytes, name: str, data: bytes) -> bytes:
    """``checkpoint`` with its member ``name`` replaced by ``data``."""
    out = io.BytesIO()
    with zipfile.ZipFile(io.BytesIO(checkpoint)) as old, zipfile.ZipFile(out, "w") as new:
        for member in old.namelist():
            if member != name:
                new.writestr(member, old.read(member))
        new.writestr(name, data)
    return out.getvalue()


def hostile(genuine: bytes, marker: Path, learner: StableBaselinesLearner, env: Any) -> dict:
    """Checkpoints that write ``marker`` if a loader unpickles them: the weights as a
    pickle, the replay buffer as an object array, and the format SB3's own ``save``
    and ``save_replay_buffer`` make (a model that loads, then a pickled buffer)."""
    import torch

    weights = io.BytesIO()
    torch.save({"state_dicts": WritesFile(marker), "variables": {}}, weights)
    with zipfile.ZipFile(io.BytesIO(genuine)) as archive:
        saved = np.load(io.BytesIO(archive.read("replay_buffer.npz")), allow_pickle=False)
        arrays = {name: saved[name] for name in saved.files}
    arrays["observations"] = np.array([WritesFile(marker)], dtype=object)
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    model = io.BytesIO()
    learner.make_model(env, steps=SOURCE_STEPS, seed=0).save(model)
    sb3_format = io.BytesIO()
    with zipfile.ZipFile(sb3_format, "w") as archive:
        archive.writestr("model.zip", model.getvalue())
        archive.writestr("replay_buffer.pkl", pickle.dumps(WritesFile(marker)))
    return {
        "weights": with_member(genuine, "parameters.pt", weights.getvalue()),
        "replay buffer": with_member(genuine, "replay_buffer.npz", buffer.getvalue()),
        "SB3's pickles": sb3_format.getvalue(),
    }


def test_a_checkpoint_that_would_run_code_is_refused_unread(env_of, tmp_path: Path) -> None:
    """Each hostile checkpoint, as a warm start, is refused with the reason and the
    design trains from scratch; as a resume point the job fails with the reason. The
    file its unpickling would write never appears."""
    source = learner_of("sac").train(
        env_of("stand-up", "arch_chain"), steps=SOURCE_STEPS, seed=0, keep_checkpoint=True
    )
    assert source.checkpoint is not None
    marker = tmp_path / "unpickled"
    env = env_of("stand-up", "arch_chain")
    checkpoints = hostile(source.checkpoint, marker, learner_of("sac"), env)
    for kind, checkpoint in checkpoints.items():
        warm = learner_of("sac")
        result = warm.train(env, steps=64, seed=0, start=Warm(checkpoint, WARM_STEPS))
        assert not marker.exists(), kind
        assert not result.warm_started and result.train_steps >= 64, kind
        assert warm.warm_problem is not None and "refused" in warm.warm_problem, kind
        resumed = learner_of("sac")
        with pytest.raises(ValueError, match="refused unread"):
            resumed.train(env, steps=SOURCE_STEPS + 32, seed=0, start=Resume(checkpoint))
        assert not marker.exists(), kind


def test_a_warm_model_keeps_every_transition_of_a_larger_source_buffer(env_of) -> None:
    """A warm start builds its model for its own budget (here a 1,000-transition buffer)
    while its source's buffer held 1,100 (a full ring, its oldest at 100): the loaded
    buffer grows to hold them all, oldest first, as the source's own held them."""
    env = env_of("stand-up", "arch_chain")
    learner = learner_of("sac")
    source = learner.make_model(env, steps=1100, seed=0)
    ring = source.replay_buffer
    rng = np.random.default_rng(0)
    for name in ("observations", "next_observations", "actions", "rewards"):
        getattr(ring, name)[:] = rng.random(getattr(ring, name).shape, dtype=np.float32)
    ring.pos, ring.full = 100, True

    warm = learner.load_checkpoint(env, learner.checkpoint(source), steps=WARM_STEPS, seed=0)
    assert learner.make_model(env, steps=WARM_STEPS, seed=0).replay_buffer.buffer_size == 1000
    loaded = warm.replay_buffer
    assert (loaded.buffer_size, loaded.pos, loaded.full) == (1100, 0, True)
    for name in ("observations", "next_observations", "actions", "rewards"):
        assert np.array_equal(getattr(loaded, name), np.roll(getattr(ring, name), -100, axis=0))
