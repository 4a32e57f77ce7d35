"""The service checks a new study's task against adclient's catalogue, without importing
the worker; these tests keep that catalogue equal to what the worker really has."""

from __future__ import annotations

import inspect
import re
from pathlib import Path

import pytest
from pydantic import ValidationError

from adclient.schemas import (
    LEARNER_NAMES,
    TASK_NAMES,
    TASK_OPTIONS,
    TUNABLE_LEARNERS,
    NewTaskConfig,
    TaskOptions,
)
from adworker import evaluate
from adworker.learners import LEARNERS, StableBaselinesLearner
from adworker.tasks import TASKS, base
from tests.workers.robots import make_job, stand_up_specs

HALF_PI = 1.5707963267948966


def test_task_and_learner_names_are_the_workers() -> None:
    assert set(TASK_NAMES) == set(TASKS)
    assert set(LEARNER_NAMES) == set(LEARNERS)
    tunable = {name for name, cls in LEARNERS.items() if issubclass(cls, StableBaselinesLearner)}
    assert set(TUNABLE_LEARNERS) == tunable


def _options_read(cls: type) -> set[str]:
    """The option keys a task class (and the task classes it extends) reads."""
    keys: set[str] = set()
    for klass in cls.__mro__:
        if klass.__module__.startswith("adworker.tasks"):
            keys |= set(re.findall(r"options\.get\(\s*\"(\w+)\"", inspect.getsource(klass)))
    return keys


def test_every_option_a_task_reads_is_declared() -> None:
    assert set(TASK_OPTIONS) == set(TASKS)
    source = Path(evaluate.__file__).read_text()
    learner_keys = set(re.findall(r"task\.options\.get\(\s*\"(\w+)\"", source))
    assert learner_keys == {"learner_kwargs"}
    for name, cls in TASKS.items():
        read = _options_read(cls) | learner_keys
        assert read, name
        assert read == set(TASK_OPTIONS[name].model_fields), name


def test_declared_defaults_are_the_simulators() -> None:
    fields = TaskOptions.model_fields
    assert fields["frame_skip"].default == base.DEFAULT_FRAME_SKIP
    assert fields["time_step"].default == base.DEFAULT_TIME_STEP
    assert fields["init_noise"].default == base.DEFAULT_INIT_NOISE
    assert fields["rolling_friction"].default == base.ROLLING_FRICTION
    assert fields["spinning_friction"].default == base.SPINNING_FRICTION


def test_the_shortest_episode_allowed_is_the_shortest_the_simulator_runs(tmp_path: Path) -> None:
    shortest = NewTaskConfig.model_fields["episode_steps"].metadata[0].ge
    assert shortest == 2
    with pytest.raises(ValidationError, match="episode_steps"):
        NewTaskConfig(name="stand-up", episode_steps=shortest - 1)
    job = make_job(
        "stand-up",
        stand_up_specs(HALF_PI, HALF_PI),
        episode_steps=shortest,
        train_steps=4 * shortest,
        eval_episodes=1,
    )
    evaluation = evaluate.evaluate_job(job, tmp_path / "shortest", render=False)
    assert evaluation.metrics["eval_episodes"] == 1.0
    too_short = make_job("stand-up", stand_up_specs(HALF_PI, HALF_PI), episode_steps=shortest - 1)
    with pytest.raises(ValueError, match="episode_steps >= 2"):
        evaluate.evaluate_job(too_short, tmp_path / "too-short", render=False)
