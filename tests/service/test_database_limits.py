"""Input one database would store and another refuses is a 422 on both: PostgreSQL
INTEGER ids are 32-bit and its text columns cannot hold NUL (SQLite takes either)."""

from __future__ import annotations

import copy

import pytest
from fastapi.testclient import TestClient

from tests.service.conftest import BOX_STUDY

TOO_BIG = 2**31
MANAGED = copy.deepcopy(BOX_STUDY) | {"task": {"name": "noop", "external": True}, "max_trials": 3}


def test_ids_past_32_bits_are_422_not_an_overflow(api: TestClient) -> None:
    for method, path, body in [
        ("GET", f"/api/v1/studies/{TOO_BIG}", None),
        ("GET", f"/api/v1/trials/{TOO_BIG}", None),
        ("POST", f"/api/v1/trials/{TOO_BIG}/tell", {"value": 1.0}),
        ("POST", f"/api/v1/trials/{TOO_BIG}/heartbeat", {"worker_id": "w"}),
    ]:
        response = api.request(method, path, json=body)
        assert response.status_code == 422, (path, response.text)
    assert api.get(f"/api/v1/studies/{TOO_BIG - 1}").status_code == 404


@pytest.mark.parametrize(
    ("path", "body"),
    [
        ("/api/v1/jobs/lease", {"worker_id": "w\u0000"}),
        ("/api/v1/trials/{id}/tell", {"state": "failed", "message": "bad\u0000byte"}),
        ("/api/v1/trials/{id}/tell", {"value": 1.0, "worker_id": "\u0000"}),
        ("/api/v1/trials/{id}/heartbeat", {"worker_id": "w\u0000"}),
    ],
)
def test_nul_in_text_is_422_and_stores_nothing(
    api: TestClient, path: str, body: dict[str, object]
) -> None:
    study = api.post(
        "/api/v1/studies",
        json=MANAGED,
    ).json()
    trial = api.post("/api/v1/jobs/lease", json={"worker_id": "w"}).json()
    response = api.post(path.format(id=trial["trial_id"]), json=body)
    assert response.status_code == 422, response.text
    assert "worker_id" in response.json()["detail"] or "message" in response.json()["detail"]
    trials = api.get(f"/api/v1/studies/{study['id']}/trials").json()
    assert [(t["state"], t["worker_id"], t["message"]) for t in trials] == [("running", "w", None)]


def test_text_with_other_control_and_wide_characters_is_stored(api: TestClient) -> None:
    api.post(
        "/api/v1/studies",
        json=MANAGED,
    )
    worker = "é" * 128  # 128 characters, 256 bytes: the column counts characters
    trial = api.post("/api/v1/jobs/lease", json={"worker_id": worker}).json()
    told = api.post(
        f"/api/v1/trials/{trial['trial_id']}/tell",
        json={"state": "failed", "message": "line\n\ttab \u0001 \u2603", "worker_id": worker},
    )
    assert told.status_code == 200, told.text
    assert told.json()["message"] == "line\n\ttab \u0001 \u2603"
    assert told.json()["worker_id"] == worker
