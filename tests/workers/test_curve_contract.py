"""One curve contract (issue 60): the ``curve.json`` a real ``adworker`` writes reads back
through :class:`adclient.schemas.Curve` unchanged (training points, evaluation episodes,
the trial's value as their mean), and its score text says what each task computes
(walk-forward scores the last value, the others a second-half mean): the rule each task
declares beside its ``score`` (``Task.score_rule``), checked here against what the score
computes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from adclient import Client
from adclient.plugins import catalogue
from adclient.schemas import Curve
from adclient.testing.servers import ServerProcess
from adworker import designs
from adworker.curves import env_score_text, evaluation_curve
from adworker.learners import EpisodeResult, evaluate_policy
from adworker.starts import TrainResult
from adworker.tasks.base import Task
from adworker.tasks.walk_forward import WalkForward
from tests.workers.robots import (
    HALF_PI,
    make_job,
    ppo_trained_trial,
    stand_up_specs,
    write_urdf,
)

TRAIN_STEPS = 128
"""Four PPO training episodes of stand-up's 32 steps."""


@pytest.mark.e2e
def test_a_real_workers_ppo_curve_reads_back_through_the_contract(
    server: ServerProcess, tmp_path: Path
) -> None:
    with Client(server.url) as client:
        trial = ppo_trained_trial(client, server, tmp_path, train_steps=TRAIN_STEPS)
        written = client.get_artifact(trial, "curve.json")
        curve = client.trial_curve(trial)

    assert curve.to_json() == written  # nothing the worker wrote is lost or renamed
    assert (curve.trial_id, curve.task, curve.learner) == (trial.id, "stand-up", "ppo")
    assert curve.train_steps == trial.metrics["train_steps"] == TRAIN_STEPS
    steps = [point.steps for point in curve.train]
    assert steps == [32.0, 64.0, 96.0, 128.0]  # one point per training episode
    assert all(np.isfinite(point.score) for point in curve.train)
    assert len(curve.evaluation) == trial.metrics["eval_episodes"]
    assert np.mean([episode.score for episode in curve.evaluation]) == pytest.approx(trial.value)
    assert curve.score == "mean over evaluation episodes of the per-step metric's second-half mean"
    for episode in curve.evaluation:
        assert len(episode.metric) == 32
        assert episode.score == pytest.approx(np.mean(episode.metric[16:]), abs=1e-5)


RULES = {
    "the per-step metric's second-half mean": lambda metric: float(
        np.mean(metric[len(metric) // 2 :])
    ),
    "the per-step metric's last value (at the episode's end)": lambda metric: metric[-1],
}
"""Each rule a built-in task declares, computed here on its own (docs/method.md)."""

BUILT_IN_RULES = {
    "diagonal-gesture": "the per-step metric's second-half mean",
    "lift-highest": "the per-step metric's second-half mean",
    "stand-up": "the per-step metric's second-half mean",
    "walk-forward": "the per-step metric's last value (at the episode's end)",
}
"""What each built-in task's score is (docs/method.md): walk-forward's the distance at
the episode's end."""


@pytest.mark.parametrize("task", sorted(BUILT_IN_RULES))
def test_each_built_in_tasks_declared_score_text_is_what_its_score_computes(
    task: str, tmp_path: Path
) -> None:
    spec = catalogue().tasks[task]
    robot = designs.arch_chain()
    env = spec.load_factory()(
        design=robot,
        urdf_path=write_urdf(robot, tmp_path / "robot.urdf"),
        options=spec.options.model_validate({}),
    )
    try:
        # joints swung back and forth, so the metric changes and the rules disagree on it
        def swing(observation: np.ndarray, steps=iter(range(10**6))) -> np.ndarray:
            sign = 1.0 if next(steps) % 8 < 4 else -1.0
            return np.full(env.action_space.shape, sign, dtype=np.float32)

        [episode] = evaluate_policy(env, swing, seeds=[3])
        text = env.score_text
        curve = evaluation_curve(STAND_UP_JOB, TRAINED, [episode], text)
    finally:
        env.close()
    assert text == BUILT_IN_RULES[task] == spec.load_factory().__self__.score_rule
    values = {rule(episode.metric) for rule in RULES.values()}
    assert len(values) == len(RULES), episode.metric  # the rules tell apart on this episode
    assert episode.score == pytest.approx(RULES[text](episode.metric))
    assert curve.score == f"mean over evaluation episodes of {text}"


STAND_UP_JOB = make_job("stand-up", stand_up_specs(HALF_PI, HALF_PI))
TRAINED = TrainResult(policy=lambda observation: observation, train_steps=0, curve=[])


class _HeldPose(Task):
    """A task of its own: how far its metric is from the episode's first value."""

    name = "held-pose"

    def score(self, metric: list[float]) -> float:
        """The metric's range over the episode."""
        return max(metric) - min(metric)


class _Unnamed(Task):
    name = "unnamed"

    def score(self, metric: list[float]) -> float:
        return metric[0] * 2


class _Declared(_HeldPose):
    score_rule = "the per-step metric's range"


class _Inherits(WalkForward):
    """Keeps walk-forward's score: its declared text too."""


class _Changes(WalkForward):
    def score(self, metric: list[float]) -> float:
        """The largest distance reached."""
        return max(metric)


def test_a_task_that_scores_its_own_way_is_described_by_its_own_words() -> None:
    assert Task.score_text() == "the per-step metric's second-half mean"
    assert _Declared.score_text() == "the per-step metric's range"
    # a score without a declared rule: its docstring's first line, else its name
    assert _HeldPose.score_text() == "The metric's range over the episode"
    assert _Unnamed.score_text() == "the task's own score of its per-step metric (_Unnamed.score)"
    # a subclass keeps its parent's words only while it keeps its parent's score
    assert _Inherits.score_text() == WalkForward.score_rule
    assert _Changes.score_text() == "The largest distance reached"


def test_an_env_that_declares_no_score_text_is_said_so() -> None:
    class PluginEnv:
        score_text = "minus the tip's distance, over the episode's second half"

    assert env_score_text(PluginEnv()) == PluginEnv.score_text
    assert env_score_text(object()) == "the env's episode score"


def test_the_earlier_function_curve_shape_still_reads() -> None:
    curve = Curve.model_validate_json(b'{"steps":[0,10],"y":[0.5,1.5]}')
    assert [(point.steps, point.score) for point in curve.train] == [(0, 0.5), (10, 1.5)]
    assert curve.evaluation == []


def test_a_diverged_training_episode_is_left_out_so_the_file_stays_json() -> None:
    job = make_job("stand-up", stand_up_specs(HALF_PI, HALF_PI))
    points = [{"steps": 32.0, "score": 0.5}, {"steps": 64.0, "score": float("nan")}]
    trained = TrainResult(policy=lambda observation: observation, train_steps=64, curve=points)
    episode = EpisodeResult(seed=0, score=0.25, episode_return=1.0, metric=[0.25, 0.25])
    curve = evaluation_curve(job, trained, [episode], "the env's episode score")
    read = Curve.model_validate_json(curve.to_json())
    assert [(point.steps, point.score) for point in read.train] == [(32.0, 0.5)]
    assert read.evaluation[0].episode_return == 1.0
    assert b'"return":1.0' in curve.to_json()
