"""Issue 38: a learner is told where its training starts as one typed value
(``start=Scratch() | Resume(checkpoint) | Warm(checkpoint, steps)``), with
``keep_checkpoint`` and ``reporting`` as keyword arguments, on a real task env. A plugin
learner written against the interface before (``train(env, *, steps, seed, check)``,
configured by attributes) still trains for one release, with a DeprecationWarning naming
the new way and its old attributes set; tests/workers/test_plugins_e2e.py runs such a
plugin (the fixture's ``hold``) in a real worker."""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from adclient.pruning import Checkpoint
from adworker.constant_search import ConstantTargetSearch
from adworker.learners import Learner, Reporting, TrainResult
from adworker.starts import Resume, Scratch, Start, Warm, train_learner


class OldStyle(Learner):
    """A plugin learner as docs/plugins.md described it before issue 38: it reads the
    attributes the worker assigned before ``train``."""

    name = "old-style"
    default_steps = 0

    def train(
        self, env: Any, *, steps: int, seed: int, check: Callable[[], None] = lambda: None
    ) -> TrainResult:
        self.seen = (self.reporting, self.resume_from, self.warm_start, self.keep_checkpoint)
        action = np.zeros(env.joint_count, dtype=np.float32)
        return TrainResult(policy=lambda _observation: action, train_steps=steps)


class NewStyle(Learner):
    name = "new-style"
    default_steps = 0

    def train(
        self,
        env: Any,
        *,
        steps: int,
        seed: int,
        check: Callable[[], None] = lambda: None,
        start: Start = Scratch(),
        keep_checkpoint: bool = False,
        reporting: Reporting | None = None,
    ) -> TrainResult:
        self.seen = (start, keep_checkpoint, reporting)
        action = np.zeros(env.joint_count, dtype=np.float32)
        return TrainResult(policy=lambda _observation: action, train_steps=steps)


def reporting() -> Reporting:
    return Reporting(every=8, evaluate=lambda _policy: 0.0, report=lambda _step, _value: None)


def test_an_old_style_learner_gets_its_attributes_and_a_deprecation_warning(env_of) -> None:
    env = env_of("stand-up", "arch_chain")
    learner = OldStyle()
    warm, reports = Warm(b"source", 16), reporting()
    with pytest.warns(DeprecationWarning, match=r"start, keep_checkpoint, reporting"):
        result = train_learner(
            learner, env, steps=64, seed=0, start=warm, keep_checkpoint=True, reporting=reports
        )
    assert result.train_steps == 64
    assert learner.seen == (reports, None, warm, True)
    assert (learner.warm_start.checkpoint, learner.warm_start.steps) == (b"source", 16)
    with pytest.warns(DeprecationWarning, match="docs/plugins.md"):
        train_learner(learner, env, steps=64, seed=0, start=Resume(b"own"))
    assert learner.seen == (None, b"own", None, False)


def test_a_learner_of_the_new_interface_gets_its_start_and_no_warning(env_of) -> None:
    env = env_of("stand-up", "arch_chain")
    learner, reports = NewStyle(), reporting()
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)
        train_learner(
            learner,
            env,
            steps=64,
            seed=0,
            start=Resume(b"own"),
            keep_checkpoint=True,
            reporting=reports,
        )
        assert learner.seen == (Resume(b"own"), True, reports)
        trained = train_learner(ConstantTargetSearch(), env, steps=2 * env.episode_steps, seed=0)
    assert trained.train_steps == 2 * env.episode_steps and trained.checkpoint is None


def test_a_start_is_one_frozen_value() -> None:
    """Resume and Warm cannot both be set: a start is one of them, and cannot change."""
    warm = Warm(b"source", 16)
    with pytest.raises(dataclasses.FrozenInstanceError):
        warm.steps = 32  # type: ignore[misc]
    assert Scratch() == Scratch() and Resume(b"a") != Warm(b"a", 1)


def test_a_pause_stored_before_its_budget_field_keeps_its_warm_budget() -> None:
    """A checkpoint paused by a worker of the release before carried a warm budget only
    as its transfer_steps metric: it resumes to that budget all the same."""
    old = {
        "artifact": "checkpoint.zip",
        "step": 256,
        "rung": 256,
        "metrics": {"transfer_steps": 512},
    }
    assert Checkpoint.model_validate(old).budget == 512
    assert Checkpoint.model_validate({**old, "budget": 300}).budget == 300
    assert Checkpoint.model_validate({**old, "metrics": {}}).budget is None


@pytest.mark.slow
def test_an_old_style_subclass_of_a_built_in_learner_keeps_its_warm_start(env_of) -> None:
    """A plugin of the interface before that subclasses a built-in learner and calls
    ``super().train(env, steps=, seed=, check=)`` trains from the warm start the worker
    set as an attribute, and keeps its checkpoint, instead of silently from scratch."""
    from adclient.plugins import catalogue

    built_in = type(catalogue().learner("ppo").load_factory()(None))

    class OldSubclass(built_in):  # type: ignore[misc, valid-type]
        def train(self, env: Any, *, steps: int, seed: int, check: Any = lambda: None) -> Any:
            return super().train(env, steps=steps, seed=seed, check=check)

    source = built_in(None).train(
        env_of("stand-up", "arch_chain"), steps=128, seed=0, keep_checkpoint=True
    )
    assert source.checkpoint is not None
    learner = OldSubclass(None)
    with pytest.warns(DeprecationWarning):
        trained = train_learner(
            learner,
            env_of("stand-up", "arch_chain"),
            steps=128,
            seed=1,
            start=Warm(source.checkpoint, 32),
            keep_checkpoint=True,
        )
    assert trained.warm_started and learner.warm_problem is None
    assert trained.checkpoint is not None
    with pytest.warns(DeprecationWarning):
        scratch = train_learner(learner, env_of("stand-up", "arch_chain"), steps=64, seed=1)
    assert not scratch.warm_started and scratch.checkpoint is None
