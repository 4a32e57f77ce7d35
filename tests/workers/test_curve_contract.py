"""One curve contract (issue 60): the ``curve.json`` a real ``adworker`` writes reads back
through :class:`adclient.schemas.Curve` unchanged (training points, evaluation episodes,
the trial's value as their mean), and its score text says what each task computes
(walk-forward scores the last value, the others a second-half mean)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from adclient import Client
from adclient.plugins import catalogue
from adclient.schemas import Curve
from adclient.testing.servers import ServerProcess
from adworker import designs
from adworker.curves import KNOWN_RULES, evaluation_curve, evaluation_score_text, score_rule_text
from adworker.learners import EpisodeResult, evaluate_policy
from adworker.starts import TrainResult
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


BUILT_IN_RULES = {
    "diagonal-gesture": "the per-step metric's second-half mean",
    "lift-highest": "the per-step metric's second-half mean",
    "stand-up": "the per-step metric's second-half mean",
    "walk-forward": "the per-step metric's last value (at the episode's end)",
}
"""What each built-in task's score is (docs/method.md): walk-forward's the distance at
the episode's end."""


@pytest.mark.parametrize("task", sorted(catalogue().tasks))
def test_each_tasks_score_text_names_the_rule_its_scores_follow(task: str, tmp_path: Path) -> None:
    spec = catalogue().tasks[task]
    robot = designs.arch_chain()
    env = spec.load_factory()(
        design=robot,
        urdf_path=write_urdf(robot, tmp_path / "robot.urdf"),
        options=spec.options.model_validate({}),
    )
    try:
        zero = np.zeros(env.action_space.shape, dtype=np.float32)
        [episode] = evaluate_policy(env, lambda observation: zero, seeds=[3])
        text = evaluation_score_text(env.record.score_of)
    finally:
        env.close()
    rules = dict(KNOWN_RULES)
    rule = text.removeprefix("mean over evaluation episodes of ")
    if rule in rules:  # the text names a rule: the episode's score is that rule's
        assert episode.score == pytest.approx(rules[rule](episode.metric))
    if task in BUILT_IN_RULES:
        assert rule == BUILT_IN_RULES[task]


def test_a_rule_of_its_own_is_named_by_its_docstring_or_its_name() -> None:
    def peak_to_peak(metric: list[float]) -> float:
        """The metric's range over the episode."""
        return max(metric) - min(metric)

    def unnamed(metric: list[float]) -> float:
        return metric[0] * 2

    def needs_a_real_episode(metric: list[float]) -> float:
        raise RuntimeError("no episode")

    assert score_rule_text(peak_to_peak) == "The metric's range over the episode"
    assert score_rule_text(unnamed).startswith("the task's own score of its per-step metric")
    assert "needs_a_real_episode" in score_rule_text(needs_a_real_episode)


def test_the_earlier_function_curve_shape_still_reads() -> None:
    curve = Curve.model_validate_json(b'{"steps":[0,10],"y":[0.5,1.5]}')
    assert [(point.steps, point.score) for point in curve.train] == [(0, 0.5), (10, 1.5)]
    assert curve.evaluation == []


def test_a_diverged_training_episode_is_left_out_so_the_file_stays_json() -> None:
    job = make_job("stand-up", stand_up_specs(HALF_PI, HALF_PI))
    points = [{"steps": 32.0, "score": 0.5}, {"steps": 64.0, "score": float("nan")}]
    trained = TrainResult(policy=lambda observation: observation, train_steps=64, curve=points)
    episode = EpisodeResult(seed=0, score=0.25, episode_return=1.0, metric=[0.25, 0.25])
    curve = evaluation_curve(job, trained, [episode], score_of=None)
    read = Curve.model_validate_json(curve.to_json())
    assert [(point.steps, point.score) for point in read.train] == [(32.0, 0.5)]
    assert read.evaluation[0].episode_return == 1.0
    assert b'"return":1.0' in curve.to_json()
