"""A study with the ``mpc`` learner end to end (issue 59): ``task.simulator: mujoco`` with
a real adserver and a real adworker reaching a score, its curve and replay the worker's
usual ones; and what it cannot run refused at creation with a 422 naming why."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import httpx
import pytest

from adclient import Client
from adclient.testing.workers import WorkerProcess
from tests.workers.test_engines_e2e import one_design_study

pytestmark = pytest.mark.e2e

PLANNER = {"samples": 8, "horizon": 6, "knots": 2, "replan_every": 2}


def mpc_study(name: str, **task: Any) -> dict[str, Any]:
    body = one_design_study(name, learner="mpc", **task)
    body["max_trials"] = 1
    return body


def test_a_mpc_study_on_mujoco_reaches_a_score_through_a_real_worker(
    server, tmp_path: Path
) -> None:
    body = mpc_study("mpc", simulator="mujoco")
    body["task"]["options"] = {"learner_kwargs": PLANNER}
    with Client(server.url) as client:
        study = client.create_study(body)
        engines = {learner.name: learner.simulators for learner in client.learners()}
        assert engines["mpc"] == ["mujoco"] and engines["ppo"] == ["pybullet", "mujoco"]
        worker = WorkerProcess(server, tmp_path, "mpc", "--max-jobs", "1")
        try:
            assert worker.wait() == 0, worker.log()
        finally:
            worker.stop()
        (trial,) = client.trials(study.id)
        assert trial.state == "complete", worker.log()
        # the arch stands (lying, its middle link is at its radius, 0.04 m)
        assert trial.value is not None and trial.value > 0.2, trial.value
        assert trial.metrics["train_steps"] == 0  # nothing trained
        # its rollouts are simulation: many times the two episodes' own 2 x 32 x 12 steps
        assert trial.metrics["sim_steps"] > 10 * 2 * 32 * 12
        curve = json.loads(client.get_artifact(trial, "curve.json"))
        assert curve["learner"] == "mpc" and curve["train"] == []
        assert [len(e["metric"]) for e in curve["evaluation"]] == [32, 32]
        assert client.get_artifact(trial, "replay.json")


def test_what_mpc_cannot_run_is_refused_at_creation_naming_why(server) -> None:
    url = f"{server.url}/api/v1/studies"

    def refused(body: dict[str, Any]) -> str:
        answer = httpx.post(url, json=body, timeout=60)
        assert answer.status_code == 422, answer.text
        return str(answer.json()["detail"])

    for engine in ({"simulator": "pybullet"}, {}):  # named, or the default
        detail = refused(mpc_study("on pybullet", **engine))
        assert "learner 'mpc' does not run on simulator 'pybullet'" in detail, detail
        assert "its simulators: mujoco" in detail, detail
    over = mpc_study("over budget", simulator="mujoco")
    over["task"]["options"] = {
        "learner_kwargs": {"samples": 256, "horizon": 64, "max_rollout_steps": 10_000}
    }
    detail = refused(over)
    assert "one plan simulates 16,384 control steps" in detail, detail
    assert "more than max_rollout_steps 10,000" in detail, detail
    beyond = mpc_study("beyond the limit", simulator="mujoco")
    beyond["task"]["options"] = {"learner_kwargs": {"max_rollout_steps": 10_000_000}}
    assert "max_rollout_steps" in refused(beyond)
    transfer = mpc_study("transfer", simulator="mujoco", transfer="nearest")
    assert "learner 'mpc' cannot start from another design's controller" in refused(transfer)
    assert httpx.get(url, timeout=60).json() == [], "a refused study was stored"
