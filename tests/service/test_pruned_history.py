"""What a proposer sees of pruned trials: their last value as an observation by default
(``pruner.pruned_as: last_value``), nothing with ``left_out``; never pending or failed."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from fastapi.testclient import TestClient

from adservice import repository
from adservice.db import Database
from adservice.services.configs import StudyConfigs
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
            history = repository.study_history(
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
