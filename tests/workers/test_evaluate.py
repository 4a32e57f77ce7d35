"""Learners and the evaluation pipeline on real designs, real PyBullet, no network."""

from __future__ import annotations

import json
import math
import xml.etree.ElementTree as ElementTree

import numpy as np
import pytest
from pydantic import ValidationError

from adclient.schemas import BoxParam, BoxSpace, NewTaskConfig
from adworker.constant_search import ConstantTargetSearch
from adworker.evaluate import evaluate_job, evaluation_seeds
from adworker.learners import evaluate_policy
from adworker.runner import Cancelled, JobError
from tests.workers.robots import HALF_PI, make_job, stand_up_specs

SEEDS = [0, 1, 2]


def _fast_scores(env, seeds: list[int]) -> list[float]:
    scores = []
    for seed in seeds:
        fast = ConstantTargetSearch()
        trained = fast.train(env, steps=fast.default_steps, seed=seed)
        episodes = evaluate_policy(env, trained.policy, [1000 + 10 * seed + k for k in range(3)])
        scores.append(float(np.mean([episode.score for episode in episodes])))
    return scores


def test_fast_learner_separates_arch_from_along_links_on_every_seed(env_of) -> None:
    arch = env_of("stand-up", "arch_chain")
    along = env_of("stand-up", "along_links_chain")
    try:
        arch_scores = _fast_scores(arch, SEEDS)
        along_scores = _fast_scores(along, SEEDS)
    finally:
        arch.close()
        along.close()
    assert min(arch_scores) > 0.3, arch_scores
    assert max(along_scores) < 0.05, along_scores  # b lies at its radius, 0.04


def test_fast_learner_separates_crossed_from_parallel_axes_on_the_diagonal(env_of) -> None:
    crossed = env_of("diagonal-gesture", "crossed_chain")
    parallel = env_of("diagonal-gesture", "parallel_chain")
    try:
        crossed_scores = _fast_scores(crossed, SEEDS)
        parallel_scores = _fast_scores(parallel, SEEDS)
    finally:
        crossed.close()
        parallel.close()
    assert min(crossed_scores) > 0.9, crossed_scores
    assert max(parallel_scores) < math.sqrt(2 / 3) + 0.01, parallel_scores


def test_fast_learner_stays_within_its_budget(env_of) -> None:
    env = env_of("stand-up", "arch_chain")
    try:
        trained = ConstantTargetSearch().train(env, steps=10 * env.episode_steps, seed=0)
    finally:
        env.close()
    assert trained.train_steps <= 10 * env.episode_steps
    assert len(trained.curve) == trained.train_steps // env.episode_steps


def test_evaluate_job_reports_score_metrics_and_artifacts(tmp_path) -> None:
    job = make_job("stand-up", stand_up_specs(HALF_PI, HALF_PI))
    evaluation = evaluate_job(job, tmp_path)

    assert evaluation.value > 0.3  # the arch stands
    metrics = evaluation.metrics
    assert metrics["score_mean"] == evaluation.value
    assert metrics["eval_episodes"] == job.task.eval_episodes
    assert metrics["train_steps"] == ConstantTargetSearch.default_steps
    assert metrics["sim_steps"] > 0
    for stage in ("decode", "urdf", "env", "train", "evaluate", "render"):
        assert metrics[f"time_{stage}_s"] >= 0
    assert metrics["time_total_s"] >= metrics["time_train_s"]
    # The design as built (three 0.4 m links of 1 kg) and its motors while evaluated.
    assert metrics["mass"] == pytest.approx(3.0)
    assert metrics["link_length"] == pytest.approx(1.2)
    assert 0.0 < metrics["effort"] <= 20.0  # the joints' effort limit
    assert metrics["energy"] > 0.0  # the arch is raised from lying flat in every episode
    assert all(math.isfinite(value) for value in metrics.values())

    artifacts = {artifact.name: artifact for artifact in evaluation.artifacts}
    assert set(artifacts) == {"robot.urdf", "robot.png", "curve.json", "replay.json"}
    robot = ElementTree.fromstring(artifacts["robot.urdf"].data)
    assert sorted(link.get("name") for link in robot.iter("link")) == ["a", "b", "c"]
    assert artifacts["robot.png"].data.startswith(b"\x89PNG\r\n\x1a\n")
    assert artifacts["robot.png"].content_type == "image/png"
    curve = json.loads(artifacts["curve.json"].data)
    assert [point["seed"] for point in curve["evaluation"]] == evaluation_seeds(job.task)
    assert len(curve["train"]) == ConstantTargetSearch.default_steps // 32
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


def test_evaluate_job_rejects_an_unknown_learner_naming_the_installed_ones(tmp_path) -> None:
    job = make_job("stand-up", stand_up_specs(HALF_PI, HALF_PI), learner="hill-climb")
    with pytest.raises(
        JobError, match=r"unknown learner .hill-climb.*ddpg, fast, mpc, ppo, ppo-batch, sac, td3"
    ):
        evaluate_job(job, tmp_path)


def test_evaluate_job_rejects_an_unknown_task_and_kwargs_for_fast(tmp_path) -> None:
    job = make_job("stand-up", stand_up_specs(HALF_PI, HALF_PI))
    unknown = job.model_copy(update={"task": job.task.model_copy(update={"name": "juggle"})})
    with pytest.raises(JobError, match=r"unknown task .juggle.*stand-up"):
        evaluate_job(unknown, tmp_path)
    tuned = job.task.model_copy(update={"options": {"learner_kwargs": {"gamma": 0.9}}})
    with pytest.raises(JobError, match="learner 'fast' takes no learner_kwargs"):
        evaluate_job(job.model_copy(update={"task": tuned}), tmp_path)


def test_learner_kwargs_reach_the_stable_baselines_model(env_of) -> None:
    from adworker.evaluate import make_learner, task_options

    job = make_job("stand-up", stand_up_specs(HALF_PI, HALF_PI), learner="ppo")
    options = {"learner_kwargs": {"gamma": 0.5, "n_epochs": 2}}
    task = job.task.model_copy(update={"options": options})
    learner = make_learner(task, task_options(task))
    env = env_of("stand-up", "arch_chain")
    try:
        model = learner.make_model(env, steps=2048, seed=0)
    finally:
        env.close()
    assert (model.gamma, model.n_epochs) == (0.5, 2)
    assert model.learning_rate == 1e-3  # the learner's own default where not overridden


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


def test_the_shortest_episode_allowed_is_the_shortest_the_simulator_runs(tmp_path) -> None:
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
    evaluation = evaluate_job(job, tmp_path / "shortest", render=False)
    assert evaluation.metrics["eval_episodes"] == 1.0
    too_short = make_job("stand-up", stand_up_specs(HALF_PI, HALF_PI), episode_steps=shortest - 1)
    with pytest.raises(ValueError, match="episode_steps"):
        evaluate_job(too_short, tmp_path / "too-short", render=False)


def test_secondary_metrics_measure_the_design_and_its_evaluation_episodes(tmp_path) -> None:
    """mass and link_length follow the decoded design; effort and energy are the
    evaluation episodes' (training unmetered): the trained policy re-run on a fresh env
    over the same seeds meters the same figures."""
    from adclient.plugins import catalogue
    from adworker.evaluate import task_options

    short = evaluate_job(
        make_job("stand-up", stand_up_specs(HALF_PI, HALF_PI, length=0.3), train_steps=64),
        tmp_path / "short",
    )
    job = make_job("stand-up", stand_up_specs(HALF_PI, HALF_PI, length=0.55), train_steps=64)
    long = evaluate_job(job, tmp_path / "long")
    assert short.metrics["link_length"] == pytest.approx(0.9)
    assert long.metrics["link_length"] == pytest.approx(1.65)
    assert short.metrics["mass"] == long.metrics["mass"] == pytest.approx(3.0)

    assert long.train is not None
    env = (
        catalogue()
        .task("stand-up")
        .load_factory()(
            design=long.design, urdf_path=long.urdf_path, options=task_options(job.task)
        )
    )
    try:
        meter = env.meter_motors()
        evaluate_policy(env, long.train.policy, evaluation_seeds(job.task))
    finally:
        env.close()
    assert len(meter.episode_energy) == job.task.eval_episodes
    assert long.metrics["energy"] == pytest.approx(meter.energy, rel=1e-9)
    assert long.metrics["effort"] == pytest.approx(meter.effort, rel=1e-9)


def test_evaluate_job_builds_on_the_studys_engine_and_refuses_an_unknown_one(tmp_path) -> None:
    specs = stand_up_specs(HALF_PI, HALF_PI)
    on = {
        engine: evaluate_job(make_job("stand-up", specs, train_steps=256, simulator=engine),
                             tmp_path / engine)
        for engine in ("pybullet", "mujoco")
    }  # fmt: skip
    for evaluation in on.values():  # the arch stands on either engine
        assert evaluation.value > 0.3 and evaluation.metrics["sim_steps"] > 0
    assert on["mujoco"].value != on["pybullet"].value  # another engine simulated it
    stored = make_job("stand-up", specs, simulator="gazebo")  # a study stored with it
    with pytest.raises(JobError, match="'stand-up' does not run on simulator 'gazebo'"):
        evaluate_job(stored, tmp_path / "gazebo")
