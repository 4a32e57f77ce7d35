"""The new built-in tasks end to end (issue 60): track-velocity and carry-payload on
MuJoCo, reach-workspace under torque control on PyBullet, each with randomised physics,
through a real adserver and a real adworker with the ``fast`` learner; and the physics
options out of range refused at creation with a 422 naming the option."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import httpx
import pytest
import yaml

from adclient import Client
from adclient.plugins import catalogue
from adclient.testing.workers import WorkerProcess
from tests.workers.robots import EXAMPLES

pytestmark = pytest.mark.e2e


def study(task: str, simulator: str, **options: Any) -> dict[str, Any]:
    """examples/one-design.yaml (three 0.4 m links, both axes across the chain) on
    ``task``, one trial, a small budget."""
    body = yaml.safe_load((EXAMPLES / "one-design.yaml").read_text())
    body.update(name=task, max_trials=1)
    body["task"].update(
        name=task, simulator=simulator, train_steps=128, eval_episodes=2, options=options
    )
    return body


STUDIES = {
    "track-velocity": ("mujoco", {"speeds": [0.1, 0.2], "mass_scale": [0.8, 1.2]}),
    "carry-payload": ("mujoco", {"payload_link": "b", "friction": [0.6, 1.2]}),
    "reach-workspace": (
        "pybullet",
        {"control": "torque", "motor_strength": [0.5, 1.0], "episode_steps": 24},
    ),
}
METRICS = {
    "track-velocity": {"task.fell", "task.speed", "task.power"},
    "carry-payload": {"task.fell", "task.dropped"},
    "reach-workspace": {"task.distance"},
}


def test_the_new_tasks_run_end_to_end_on_both_engines(server, tmp_path: Path) -> None:
    with Client(server.url) as client:
        created = {
            name: client.create_study(study(name, engine, **options))
            for name, (engine, options) in STUDIES.items()
        }
        tasks = {task.name: task for task in client.tasks()}
        for name in STUDIES:
            assert tasks[name].simulators == ["pybullet", "mujoco"]
        worker = WorkerProcess(
            server, tmp_path, "new-tasks", "--no-render", "--max-jobs", str(len(STUDIES))
        )
        try:
            assert worker.wait() == 0, worker.log()
        finally:
            worker.stop()
        for name, handle in created.items():
            [trial] = client.trials(handle.id)
            assert trial.state == "complete", (name, worker.log())
            assert trial.value is not None and math.isfinite(trial.value)
            assert METRICS[name] <= set(trial.metrics), (name, trial.metrics)
            rule = catalogue().task(name).load_factory().__self__.score_rule
            assert client.trial_curve(trial).score == f"mean over evaluation episodes of {rule}"
        [reach] = client.trials(created["reach-workspace"].id)
        assert 0.0 <= reach.value <= 1.0 and reach.metrics["task.distance"] > 0.0
        [carry] = client.trials(created["carry-payload"].id)
        assert carry.metrics["task.dropped"] in (0.0, 0.5, 1.0)


REFUSED = [
    ({"mass_scale": [0.5, 20.0]}, "task.options: mass_scale.1:"),
    ({"friction": [2.0, 1.0]}, "task.options: friction: a range is [low, high]"),
    ({"motor_strength": [0.0, 1.0]}, "task.options: motor_strength.0:"),
    ({"control": "velocity"}, "task.options: control:"),
    ({"targets": 12, "episode_steps": 8}, "targets (12) must be at most episode_steps (8)"),
]


def test_physics_options_out_of_range_are_refused_naming_them(server) -> None:
    url = f"{server.url}/api/v1/studies"
    for options, named in REFUSED:
        answer = httpx.post(url, json=study("reach-workspace", "mujoco", **options), timeout=60)
        assert answer.status_code == 422, answer.text
        assert named in answer.json()["detail"], answer.text
    assert httpx.get(url, timeout=60).json() == [], "a refused study was stored"
