"""What a proposer sees of pruned trials: their last value as an observation by default
(``pruner.pruned_as: last_value``), nothing with ``left_out``; never pending or failed.
Paused trials (ASHA with promotion) the same while paused, pending once promoted."""

from __future__ import annotations

import copy
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from adservice.db import Database
from adservice.repository import studies as study_repo
from adservice.services.configs import StudyConfigs
from adservice.services.trials import proposer_history
from adservice.settings import Settings
from tests.service.conftest import BOX_STUDY


@pytest.mark.parametrize("pruned_as", ["last_value", "left_out"])
def test_history_counts_a_pruned_trial_as_its_pruner_says(
    api: TestClient, settings: Settings, pruned_as: str
) -> None:
    body = copy.deepcopy(BOX_STUDY) | {"pruner": {"name": "median", "pruned_as": pruned_as}}
    study = api.post("/api/v1/studies", json=body).json()
    asked = api.post(f"/api/v1/studies/{study['id']}/ask", json={"count": 4}).json()["trials"]
    complete, pruned, silent, failed = (trial["id"] for trial in asked)
    assert api.post(f"/api/v1/trials/{complete}/tell", json={"value": 3.0}).status_code == 200
    api.post(f"/api/v1/trials/{pruned}/report", json={"step": 7, "value": 0.5})
    assert api.post(f"/api/v1/trials/{pruned}/tell", json={"state": "pruned"}).status_code == 200
    # Pruned before any report: no value to stand for it, so it is left out either way.
    assert api.post(f"/api/v1/trials/{silent}/tell", json={"state": "pruned"}).status_code == 200
    api.post(f"/api/v1/trials/{failed}/tell", json={"state": "failed"})
    database = Database(settings.database_url)
    try:
        config = StudyConfigs(database).get(study["id"])
        assert config.pruner.pruned_as == pruned_as
        with database.read() as session:
            history = study_repo.study_history(
                session,
                study_id=study["id"],
                dim=2,
                pruned_as_observed=config.pruner.pruned_as == "last_value",
            )
    finally:
        database.engine.dispose()
    by_id = {trial["id"]: trial["vector"] for trial in asked}
    expected = [complete, pruned] if pruned_as == "last_value" else [complete]
    np.testing.assert_allclose(history.X, [by_id[i] for i in expected])
    np.testing.assert_allclose(history.y, [3.0, 0.5][: len(expected)])
    np.testing.assert_allclose(history.failed, [by_id[failed]])
    assert history.pending.shape == (0, 2)


@pytest.mark.parametrize("pruned_as", ["last_value", "left_out"])
def test_a_paused_trial_is_counted_once_observed_then_pending_once_promoted(
    api: TestClient, settings: Settings, pruned_as: str
) -> None:
    """Under ASHA with promotion a paused trial is its rung value (as a pruned one is,
    or left out), neither pending nor complete; promoted, it is pending only."""
    options = {"min_resource": 10, "reduction_factor": 2, "promotion": True}
    body = copy.deepcopy(BOX_STUDY) | {
        "pruner": {"name": "asha", "options": options, "pruned_as": pruned_as},
        "task": {"name": "curve", "external": True},
        "max_trials": 4,
    }
    study = api.post("/api/v1/studies", json=body).json()

    def leased(worker: str, value: float) -> dict[str, Any]:
        job = api.post("/api/v1/jobs/lease", json={"worker_id": worker, "tasks": ["curve"]})
        report = {"step": 10, "value": value, "worker_id": worker}
        answer = api.post(f"/api/v1/trials/{job.json()['trial_id']}/report", json=report)
        assert answer.status_code == 200, answer.text
        return {**job.json(), **answer.json()}

    complete = leased("wa", 1.0)
    told = api.post(
        f"/api/v1/trials/{complete['trial_id']}/tell", json={"value": 3.0, "worker_id": "wa"}
    )
    assert told.status_code == 200, told.text
    paused = leased("wb", 0.5)
    assert paused["pause"] is True
    api.put(
        f"/api/v1/trials/{paused['trial_id']}/artifacts/checkpoint.zip",
        params={"worker_id": "wb"},
        content=b"state",
    )
    pause = {"worker_id": "wb", "step": 10}
    assert api.post(f"/api/v1/trials/{paused['trial_id']}/pause", json=pause).status_code == 200
    running = leased("wc", 0.3)  # told to pause, but still running here
    database = Database(settings.database_url)
    try:
        config = StudyConfigs(database).get(study["id"])
        with database.read() as session:
            before = proposer_history(session, config)
        # A fourth value at rung 10 ([1.0, 0.5, 0.3, 0.1]): the top half takes in 0.5.
        leased("wd", 0.1)
        with database.read() as session:
            after = proposer_history(session, config)
    finally:
        database.engine.dispose()
    observed = [complete, paused] if pruned_as == "last_value" else [complete]
    np.testing.assert_allclose(before.X, [job["vector"] for job in observed])
    np.testing.assert_allclose(before.y, [3.0, 0.5][: len(observed)])
    np.testing.assert_allclose(before.pending, [running["vector"]])
    np.testing.assert_allclose(after.X, [complete["vector"]])
    assert len(after.pending) == 3  # the promoted trial, the running one and the fourth
    assert any(np.allclose(row, paused["vector"]) for row in after.pending)
    assert after.failed.shape == (0, 2)
