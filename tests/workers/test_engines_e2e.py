"""A study on MuJoCo end to end (issue 59): ``task.simulator: mujoco`` with a real adserver
and a real adworker, the ``fast`` learner, beside the same study on PyBullet; a simulator
that is not one, or what the batched learner (``ppo-batch``) cannot do, refused with a
422 naming it. (Studies with the batched learners on either engine:
tests/workers/test_batched.py.)"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import httpx
import pytest
import yaml

from adclient import Client
from adclient.testing.workers import WorkerProcess
from tests.workers.robots import EXAMPLES

pytestmark = pytest.mark.e2e

REPEATS = 2


def one_design_study(name: str, **task: Any) -> dict[str, Any]:
    """examples/one-design.yaml (the stand-up arch, three 0.4 m links), two repeats."""
    body = yaml.safe_load((EXAMPLES / "one-design.yaml").read_text())
    body.update(name=name, max_trials=REPEATS)
    body["task"].update(train_steps=256, eval_episodes=2, **task)
    return body


def test_a_mujoco_study_runs_end_to_end_beside_the_same_study_on_pybullet(
    server, tmp_path: Path
) -> None:
    with Client(server.url) as client:
        engines = ("mujoco", "pybullet")
        studies = {
            engine: client.create_study(one_design_study(engine, simulator=engine))
            for engine in engines
        }
        tasks = {task.name: task for task in client.tasks()}
        assert tasks["stand-up"].simulators == ["pybullet", "mujoco"]
        worker = WorkerProcess(server, tmp_path, "engines", "--max-jobs", str(2 * REPEATS))
        try:
            assert worker.wait() == 0, worker.log()
        finally:
            worker.stop()
        values = {}
        stored = {info.id: info for info in client.studies()}
        for engine, study in studies.items():
            assert stored[study.id].task.simulator == engine
            trials = client.trials(study.id)
            assert [t.state for t in trials] == ["complete"] * REPEATS, worker.log()
            for trial in trials:
                assert trial.metrics["sim_steps"] > 0
                picture = client.get_artifact(trial, "robot.png")
                assert picture.startswith(b"\x89PNG")
            values[engine] = [t.value for t in trials]
    # both engines lift the arch's middle link well off the ground (lying: its radius,
    # 0.04 m), and the MuJoCo study's scores are its own engine's, not PyBullet's
    for engine, scores in values.items():
        assert all(score > 0.2 for score in scores), (engine, values)
    assert set(values["mujoco"]).isdisjoint(values["pybullet"]), values


def test_a_simulator_that_is_not_one_is_refused_naming_it(server) -> None:
    url = f"{server.url}/api/v1/studies"
    answer = httpx.post(url, json=one_design_study("bogus", simulator="bogus"), timeout=60)
    assert answer.status_code == 422, answer.text
    detail = answer.json()["detail"]
    assert "'bogus' is not a simulator" in detail and "pybullet, mujoco" in detail, detail
    assert httpx.get(url, timeout=60).json() == [], "a refused study was stored"


def test_the_batched_learner_refuses_what_it_cannot_do_naming_it(server) -> None:
    """A shared controller (``ppo``'s alone) and options past the update budget are each
    refused with a 422 at study creation, naming what is refused."""
    url = f"{server.url}/api/v1/studies"
    shared = one_design_study("shared", learner="ppo-batch", transfer="shared")
    answer = httpx.post(url, json=shared, timeout=60)
    assert answer.status_code == 422, answer.text
    assert "ppo-batch" in answer.text and "shared" in answer.text, answer.text
    costly = one_design_study("costly", learner="ppo-batch")
    costly["task"]["train_steps"] = 1_000_000
    costly["task"]["options"] = {
        "learner_kwargs": {"n_envs": 1, "unroll": 1, "n_minibatches": 1, "n_epochs": 100}
    }
    answer = httpx.post(url, json=costly, timeout=60)
    assert answer.status_code == 422, answer.text
    assert "gradient updates" in answer.text and "n_epochs 100" in answer.text, answer.text
    assert httpx.get(url, timeout=60).json() == [], "a refused study was stored"
