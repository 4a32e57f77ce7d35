"""A multi-fidelity study end to end (issue 61): a real adserver and a real adworker
training PPO, each trial to the fidelity its proposal chose; the study's best is its
best trial at the top fidelity; a fidelity that cannot be trained to is refused (422)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import httpx
import pytest
import yaml

from adclient import Client
from adclient.testing.servers import ServerProcess
from adclient.testing.workers import PATIENCE, WorkerProcess

pytestmark = pytest.mark.e2e

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "multi-fidelity.yaml"
GRID = (64, 128, 256)
"""The tiny study's fidelities (train_steps): min 64, max 256, three levels."""


def tiny_study(max_trials: int) -> dict[str, Any]:
    """examples/multi-fidelity.yaml at PPO budgets of a few rollouts of 64 steps."""
    body = yaml.safe_load(EXAMPLE.read_text())
    body["proposer"] = {"name": "qei", "n_initial": 2, "seed": 3}
    body["task"]["fidelity"] = {"min": GRID[0], "max": GRID[-1], "levels": len(GRID)}
    body["task"]["eval_episodes"] = 1
    body["task"]["options"] = {"learner_kwargs": {"n_steps": 64, "batch_size": 32, "n_epochs": 1}}
    body["max_trials"] = max_trials
    return body


def test_trials_train_to_their_fidelity_and_the_best_is_at_the_top(
    server: ServerProcess, tmp_path: Path
) -> None:
    worker = WorkerProcess(server, tmp_path, "mf", "--no-render", "--max-jobs", "6")
    try:
        with Client(server.url) as client:
            study = client.create_study(tiny_study(max_trials=6))
            info = study.wait(poll=0.3, timeout=PATIENCE)
            assert info.n_complete == 6, worker.log()
            trials = study.trials
            fidelities = [trial.info["fidelity"] for trial in trials]
            assert set(fidelities) <= set(GRID)
            assert fidelities[:2] == [GRID[0], GRID[0]]  # the start: short runs
            assert fidelities[-2:] == [GRID[-1], GRID[-1]]  # the end: at the target
            for trial in trials:  # the worker trained each to its own fidelity
                assert trial.metrics["train_steps"] == trial.info["fidelity"], trial
                assert trial.info["fidelity_max"] == GRID[-1]
            top = [t for t in trials if t.info["fidelity"] == GRID[-1]]
            best = study.best_trial
            assert best is not None and best.info["fidelity"] == GRID[-1]
            assert best.value == max(t.value for t in top)
            assert info.best_value == best.value
    finally:
        worker.stop()


REFUSED = [
    ({"learner": "fast", "options": {}}, "learner 'fast' has no training steps"),
    ({"train_steps": 128}, "train_steps 128 is not the top fidelity"),
    ({"fidelity": {"min": 256, "max": 64}}, "min 256 must be below max 64"),
    ({"fidelity": {"min": 64, "max": 20_000_000}}, "fidelity.max"),
    ({"fidelity": {"param": "episode_steps", "min": 8, "max": 32}}, "fidelity.param"),
    ({"transfer": "nearest"}, "task.fidelity with transfer 'nearest'"),
]
"""Task changes to the tiny study that no worker could train, and what the 422 names."""


def test_a_fidelity_that_cannot_be_trained_to_is_refused_naming_it(server: ServerProcess) -> None:
    with httpx.Client(base_url=server.url, verify=False, timeout=30) as http:
        for change, named in REFUSED:
            body = tiny_study(max_trials=2)
            body["task"].update(change)
            response = http.post("/api/v1/studies", json=body)
            assert response.status_code == 422, (change, response.text)
            assert named in response.text, (change, response.text)
        for study, named in [
            ({"proposer": {"name": "tpe"}}, "proposer 'tpe' does not choose fidelities"),
            ({"pruner": {"name": "median"}}, "task.fidelity with pruner 'median'"),
        ]:
            response = http.post("/api/v1/studies", json={**tiny_study(max_trials=2), **study})
            assert response.status_code == 422, (study, response.text)
            assert named in response.text, (study, response.text)
        assert http.get("/api/v1/studies").json() == []  # nothing stored
