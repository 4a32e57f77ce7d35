"""Learners and the evaluation pipeline on real designs, real PyBullet, no network."""

from __future__ import annotations

import json
import math
import xml.etree.ElementTree as ElementTree

import numpy as np
import pytest

from adclient.schemas import BoxParam, BoxSpace
from adworker.evaluate import Cancelled, JobError, evaluate_job, evaluation_seeds
from adworker.learners import LEARNERS, UnknownLearner, evaluate_policy, get_learner
from adworker.tasks import get_task
from tests.workers.robots import HALF_PI, make_job, stand_up_specs

SEEDS = [0, 1, 2]


def _fast_scores(env, seeds: list[int]) -> list[float]:
    scores = []
    for seed in seeds:
        trained = get_learner("fast").train(env, steps=get_learner("fast").default_steps, seed=seed)
        episodes = evaluate_policy(env, trained.policy, [1000 + 10 * seed + k for k in range(3)])
        scores.append(float(np.mean([episode.score for episode in episodes])))
    return scores


def test_fast_learner_separates_arch_from_along_links_on_every_seed(urdf_of) -> None:
    arch = get_task("stand-up")(urdf_of("arch_chain"))
    along = get_task("stand-up")(urdf_of("along_links_chain"))
    try:
        arch_scores = _fast_scores(arch, SEEDS)
        along_scores = _fast_scores(along, SEEDS)
    finally:
        arch.close()
        along.close()
    assert min(arch_scores) > 0.3, arch_scores
    assert max(along_scores) < 0.05, along_scores  # b lies at its radius, 0.04


def test_fast_learner_separates_crossed_from_parallel_axes_on_the_diagonal(urdf_of) -> None:
    crossed = get_task("diagonal-gesture")(urdf_of("crossed_chain"))
    parallel = get_task("diagonal-gesture")(urdf_of("parallel_chain"))
    try:
        crossed_scores = _fast_scores(crossed, SEEDS)
        parallel_scores = _fast_scores(parallel, SEEDS)
    finally:
        crossed.close()
        parallel.close()
    assert min(crossed_scores) > 0.9, crossed_scores
    assert max(parallel_scores) < math.sqrt(2 / 3) + 0.01, parallel_scores


def test_fast_learner_stays_within_its_budget(urdf_of) -> None:
    env = get_task("stand-up")(urdf_of("arch_chain"))
    try:
        trained = get_learner("fast").train(env, steps=10 * env.episode_steps, seed=0)
    finally:
        env.close()
    assert trained.train_steps <= 10 * env.episode_steps
    assert len(trained.curve) == trained.train_steps // env.episode_steps


def test_unknown_learner_names_the_known_ones() -> None:
    with pytest.raises(UnknownLearner, match="ddpg"):
        get_learner("hill-climb")
    assert {"fast", "ddpg", "td3", "sac", "ppo"} <= set(LEARNERS)


def test_evaluate_job_reports_score_metrics_and_artifacts(tmp_path) -> None:
    job = make_job("stand-up", stand_up_specs(HALF_PI, HALF_PI))
    evaluation = evaluate_job(job, tmp_path)

    assert evaluation.value > 0.3  # the arch stands
    metrics = evaluation.metrics
    assert metrics["score_mean"] == evaluation.value
    assert metrics["eval_episodes"] == job.task.eval_episodes
    assert metrics["train_steps"] == get_learner("fast").default_steps
    assert metrics["sim_steps"] > 0
    for stage in ("decode", "urdf", "env", "train", "evaluate", "render"):
        assert metrics[f"time_{stage}_s"] >= 0
    assert metrics["time_total_s"] >= metrics["time_train_s"]
    assert all(math.isfinite(value) for value in metrics.values())

    artifacts = {artifact.name: artifact for artifact in evaluation.artifacts}
    assert set(artifacts) == {"robot.urdf", "robot.png", "curve.json"}
    robot = ElementTree.fromstring(artifacts["robot.urdf"].data)
    assert sorted(link.get("name") for link in robot.iter("link")) == ["a", "b", "c"]
    assert artifacts["robot.png"].data.startswith(b"\x89PNG\r\n\x1a\n")
    assert artifacts["robot.png"].content_type == "image/png"
    curve = json.loads(artifacts["curve.json"].data)
    assert [point["seed"] for point in curve["evaluation"]] == evaluation_seeds(job.task)
    assert len(curve["train"]) == get_learner("fast").default_steps // 32
    assert np.mean([point["score"] for point in curve["evaluation"]]) == pytest.approx(
        evaluation.value
    )
    assert (tmp_path / "robot.urdf").read_bytes() == artifacts["robot.urdf"].data


def test_evaluate_job_is_reproducible_and_the_seed_matters(tmp_path) -> None:
    specs = stand_up_specs(HALF_PI, HALF_PI)
    first = evaluate_job(make_job("stand-up", specs, train_steps=256), tmp_path / "1")
    again = evaluate_job(make_job("stand-up", specs, train_steps=256), tmp_path / "2")
    other = evaluate_job(make_job("stand-up", specs, train_steps=256, seed=5), tmp_path / "3")
    assert first.value == again.value
    assert [e.metric for e in first.episodes] == [e.metric for e in again.episodes]
    assert [e.seed for e in other.episodes] != [e.seed for e in first.episodes]


def test_evaluate_job_scores_along_links_low(tmp_path) -> None:
    evaluation = evaluate_job(make_job("stand-up", stand_up_specs(0.0, 0.0)), tmp_path)
    assert evaluation.value < 0.05


def test_evaluate_job_honours_task_config(tmp_path) -> None:
    job = make_job(
        "stand-up",
        stand_up_specs(HALF_PI, HALF_PI),
        train_steps=64,
        eval_episodes=2,
        episode_steps=16,
    )
    evaluation = evaluate_job(job, tmp_path, render=False)
    assert evaluation.metrics["train_steps"] == 64
    assert len(evaluation.episodes) == 2
    assert all(len(episode.metric) == 16 for episode in evaluation.episodes)
    assert "robot.png" not in {artifact.name for artifact in evaluation.artifacts}


def test_evaluate_job_cancels_at_the_next_check(tmp_path) -> None:
    calls = 0

    def check() -> None:
        nonlocal calls
        calls += 1
        if calls > 3:
            raise Cancelled("lease lost")

    with pytest.raises(Cancelled, match="lease lost"):
        evaluate_job(make_job("stand-up", stand_up_specs(HALF_PI, HALF_PI)), tmp_path, check=check)


def test_evaluate_job_refuses_a_box_space(tmp_path) -> None:
    job = make_job("stand-up", stand_up_specs(HALF_PI, HALF_PI))
    job = job.model_copy(
        update={
            "space": BoxSpace(type="box", params=[BoxParam(name="x", low=0, high=1)]),
            "vector": [0.5],
        }
    )
    with pytest.raises(JobError, match="design space"):
        evaluate_job(job, tmp_path)


def test_evaluate_job_rejects_an_unknown_learner(tmp_path) -> None:
    job = make_job("stand-up", stand_up_specs(HALF_PI, HALF_PI), learner="nope")
    with pytest.raises(UnknownLearner):
        evaluate_job(job, tmp_path)


@pytest.mark.slow
@pytest.mark.parametrize("learner", ["ddpg", "ppo"])
def test_stable_baselines_learner_trains_at_a_small_budget(learner: str, tmp_path) -> None:
    steps = 320 if learner == "ddpg" else 256
    job = make_job("stand-up", stand_up_specs(HALF_PI, HALF_PI), learner=learner, train_steps=steps)
    evaluation = evaluate_job(job, tmp_path, render=False)
    assert evaluation.metrics["train_steps"] == steps
    assert evaluation.train is not None
    assert len(evaluation.train.curve) == steps // 32  # one score per training episode
    assert math.isfinite(evaluation.value)
    assert 0.0 <= evaluation.value < 1.0
