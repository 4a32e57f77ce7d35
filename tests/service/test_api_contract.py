"""The v1 HTTP contract, path by path, against the in-process app on a SQLite file."""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path
from typing import Any

import pytest
import yaml
from fastapi.testclient import TestClient

from tests.service.conftest import BOX_STUDY

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def create(api: TestClient, **changes: Any) -> dict[str, Any]:
    body = copy.deepcopy(BOX_STUDY) | changes
    response = api.post("/api/v1/studies", json=body)
    assert response.status_code == 201, response.text
    return response.json()


def ask(api: TestClient, study_id: int, count: int = 1) -> list[dict[str, Any]]:
    response = api.post(f"/api/v1/studies/{study_id}/ask", json={"count": count})
    assert response.status_code == 200, response.text
    return response.json()["trials"]


def test_healthz_and_openapi(api: TestClient) -> None:
    assert api.get("/healthz").status_code == 200
    spec = api.get("/openapi.json").json()
    assert "/api/v1/studies/{study_id}/ask" in spec["paths"]
    assert api.get("/docs").status_code == 200


def test_create_list_get_study(api: TestClient) -> None:
    study = create(api)
    assert study["state"] == "running" and study["n_trials"] == 0 and study["best_value"] is None
    assert [s["id"] for s in api.get("/api/v1/studies").json()] == [study["id"]]
    assert api.get(f"/api/v1/studies/{study['id']}").json()["name"] == "box"
    assert api.get("/api/v1/studies/999").status_code == 404


def test_ask_tell_best_roundtrip(api: TestClient) -> None:
    study = create(api)
    trials = ask(api, study["id"], count=3)
    assert [t["number"] for t in trials] == [0, 1, 2]
    assert all(t["state"] == "running" for t in trials)
    for trial in trials:
        assert -1 <= trial["params"]["x"] <= 1 and 0 <= trial["params"]["y"] <= 5
        assert trial["vector"] == [trial["params"]["x"], trial["params"]["y"]]
    for value, trial in zip([1.0, 3.0, 2.0], trials, strict=True):
        told = api.post(f"/api/v1/trials/{trial['id']}/tell", json={"value": value})
        assert told.status_code == 200 and told.json()["state"] == "complete"
    best = api.get(f"/api/v1/studies/{study['id']}/best").json()
    assert best["id"] == trials[1]["id"] and best["value"] == 3.0
    info = api.get(f"/api/v1/studies/{study['id']}").json()
    assert (info["n_trials"], info["n_complete"], info["n_running"]) == (3, 3, 0)


def test_minimize_best_is_smallest(api: TestClient) -> None:
    study = create(api, direction="minimize")
    trials = ask(api, study["id"], count=2)
    api.post(f"/api/v1/trials/{trials[0]['id']}/tell", json={"value": 5.0})
    api.post(f"/api/v1/trials/{trials[1]['id']}/tell", json={"value": -5.0})
    assert api.get(f"/api/v1/studies/{study['id']}/best").json()["value"] == -5.0


def test_best_is_404_until_a_trial_completes(api: TestClient) -> None:
    study = create(api)
    assert api.get(f"/api/v1/studies/{study['id']}/best").status_code == 404


def test_repeated_tell_is_harmless_contradiction_is_409(api: TestClient) -> None:
    study = create(api)
    (trial,) = ask(api, study["id"])
    url = f"/api/v1/trials/{trial['id']}/tell"
    assert api.post(url, json={"value": 1.5}).status_code == 200
    assert api.post(url, json={"value": 1.5}).status_code == 200
    conflict = api.post(url, json={"value": 2.5})
    assert conflict.status_code == 409 and "already complete" in conflict.json()["detail"]
    assert api.post(url, json={"state": "failed", "message": "x"}).status_code == 409
    assert api.get(f"/api/v1/studies/{study['id']}").json()["n_complete"] == 1


def test_failed_tell_and_state_filter(api: TestClient) -> None:
    study = create(api)
    first, second = ask(api, study["id"], count=2)
    failed = api.post(
        f"/api/v1/trials/{first['id']}/tell", json={"state": "failed", "message": "diverged"}
    )
    assert failed.json()["state"] == "failed" and failed.json()["message"] == "diverged"
    listed = api.get(f"/api/v1/studies/{study['id']}/trials", params={"state": "failed"})
    assert [t["id"] for t in listed.json()] == [first["id"]]
    running = api.get(f"/api/v1/studies/{study['id']}/trials", params={"state": "running"})
    assert [t["id"] for t in running.json()] == [second["id"]]


def test_trial_paging_and_ordering(api: TestClient) -> None:
    study = create(api)
    trials = ask(api, study["id"], count=10)
    for i, trial in enumerate(trials):
        api.post(f"/api/v1/trials/{trial['id']}/tell", json={"value": float((i * 7) % 10)})
    page = api.get(
        f"/api/v1/studies/{study['id']}/trials",
        params={"order_by": "value", "desc": True, "limit": 3, "offset": 1},
    )
    assert page.headers["X-Total-Count"] == "10"
    assert [t["value"] for t in page.json()] == [8.0, 7.0, 6.0]


def test_trials_sort_by_a_param_and_by_duration(api: TestClient) -> None:
    study = create(api)
    trials = ask(api, study["id"], count=6)
    for trial in trials[:4]:
        api.post(f"/api/v1/trials/{trial['id']}/tell", json={"value": 1.0})
    url = f"/api/v1/studies/{study['id']}/trials"
    by_x = api.get(url, params={"order_by": "param:x"}).json()
    xs = [t["params"]["x"] for t in by_x]
    assert xs == sorted(xs) and len(xs) == 6
    by_y = api.get(url, params={"order_by": "param:y", "desc": True}).json()
    assert [t["params"]["y"] for t in by_y] == sorted(
        (t["params"]["y"] for t in by_y), reverse=True
    )
    missing = api.get(url, params={"order_by": "param:nope"})  # no such param: by number
    assert [t["number"] for t in missing.json()] == list(range(6))
    by_duration = api.get(url, params={"order_by": "duration", "desc": True}).json()
    assert [t["state"] for t in by_duration[4:]] == ["running", "running"]  # nulls last
    for bad in ("param:", "param:x y", "param:../x", "params", "duration;"):
        refused = api.get(url, params={"order_by": bad})
        assert refused.status_code == 422, bad
        assert refused.json()["detail"].startswith("query.order_by: ")
        assert "param:NAME" in refused.json()["detail"]


def test_trials_sort_by_text_and_list_params_of_a_design(api: TestClient) -> None:
    body = yaml.safe_load((EXAMPLES / "multi-structure.yaml").read_text())
    body["proposer"] = {"name": "random", "seed": 1}
    created = api.post("/api/v1/studies", json=body)
    assert created.status_code == 201, created.text
    study_id = created.json()["id"]
    ask(api, study_id, count=8)
    url = f"/api/v1/studies/{study_id}/trials"
    structures = [
        t["params"]["structure"]
        for t in api.get(url, params={"order_by": "param:structure"}).json()
    ]
    assert structures == sorted(structures)
    for name in ("b.joint.axis", "c.joint.axis_theta", "root"):  # a list, a number, text
        listed = api.get(url, params={"order_by": f"param:{name}", "desc": True})
        assert listed.status_code == 200 and len(listed.json()) == 8, listed.text


def test_max_trials_bounds_asks(api: TestClient) -> None:
    study = create(api, max_trials=3)
    ask(api, study["id"], count=2)
    over = api.post(f"/api/v1/studies/{study['id']}/ask", json={"count": 2})
    assert over.status_code == 409 and "max_trials" in over.json()["detail"]
    ask(api, study["id"], count=1)


def test_study_completes_when_max_trials_are_told(api: TestClient) -> None:
    study = create(api, max_trials=2)
    for trial in ask(api, study["id"], count=2):
        api.post(f"/api/v1/trials/{trial['id']}/tell", json={"value": 1.0})
    assert api.get(f"/api/v1/studies/{study['id']}").json()["state"] == "complete"


def test_series_gives_columns(api: TestClient) -> None:
    study = create(api)
    trials = ask(api, study["id"], count=2)
    api.post(f"/api/v1/trials/{trials[0]['id']}/tell", json={"value": 4.0})
    series = api.get(f"/api/v1/studies/{study['id']}/series").json()
    assert series["number"] == [0, 1] and series["value"] == [4.0, None]
    assert series["state"] == ["complete", "running"]
    assert series["params"]["x"] == [trials[0]["params"]["x"], trials[1]["params"]["x"]]


BAD_STUDIES = [
    ({"space": {"type": "box", "params": []}}, "params"),
    ({"space": {"type": "box", "params": [{"name": "x", "low": 1, "high": 1}]}}, "low"),
    (
        {"space": {"type": "box", "params": [{"name": "x", "low": 0, "high": 1}] * 2}},
        "duplicate param name",
    ),
    ({"direction": "sideways"}, "direction"),
    ({"name": ""}, "name"),
    ({"proposer": {"name": "oracle"}}, "unknown proposer"),
    ({"task": {"name": "stand-up"}}, "max_trials"),
    ({"max_trials": 0}, "max_trials"),
    ({"surprise": 1}, "surprise"),
]


@pytest.mark.parametrize(("change", "named"), BAD_STUDIES)
def test_bad_study_is_422_naming_the_field_and_stores_nothing(
    api: TestClient, change: dict[str, Any], named: str
) -> None:
    response = api.post("/api/v1/studies", json=copy.deepcopy(BOX_STUDY) | change)
    assert response.status_code == 422, response.text
    assert named in response.json()["detail"]
    assert api.get("/api/v1/studies").json() == []


def test_non_finite_bounds_are_refused(api: TestClient) -> None:
    body = copy.deepcopy(BOX_STUDY)
    body["space"]["params"][0]["high"] = "Infinity"
    response = api.post("/api/v1/studies", json=body)
    assert response.status_code == 422
    assert api.get("/api/v1/studies").json() == []


@pytest.mark.parametrize(
    ("body", "named"),
    [
        ({"value": math.nan}, "value must be a finite number"),
        ({"value": -math.inf}, "value must be a finite number"),
        ({"value": "NaN"}, "value: Input should be a valid number"),
        ({"value": "Infinity"}, "value: Input should be a valid number"),
        ({}, "value is required"),
        ({"state": "failed", "value": 1.0}, "no value"),
        ({"value": 1.0, "metrics": {"loss": math.nan}}, "metric 'loss' must be a finite"),
        ({"value": 1.0, "metrics": {"loss": "NaN"}}, "metrics.loss: Input should be a valid"),
        ({"value": 1.0, "state": "exploded"}, "state"),
    ],
)
def test_bad_tell_is_422_and_stores_nothing(
    api: TestClient, body: dict[str, Any], named: str
) -> None:
    """Python's JSON reads the tokens NaN and Infinity, which a tell refuses as not
    finite; the strings "NaN" and "Infinity" are not numbers at all."""
    study = create(api)
    (trial,) = ask(api, study["id"])
    response = api.post(
        f"/api/v1/trials/{trial['id']}/tell",
        content=json.dumps(body),  # NaN and Infinity as JSON's extension writes them
        headers={"Content-Type": "application/json"},
    )
    assert response.status_code == 422 and named in response.json()["detail"]
    assert api.get(f"/api/v1/trials/{trial['id']}").json()["state"] == "running"


@pytest.mark.parametrize("count", [0, 65, -1, "many"])
def test_bad_ask_count(api: TestClient, count: Any) -> None:
    study = create(api)
    response = api.post(f"/api/v1/studies/{study['id']}/ask", json={"count": count})
    assert response.status_code == 422 and "count" in response.json()["detail"]
    assert api.get(f"/api/v1/studies/{study['id']}").json()["n_trials"] == 0


def test_unknown_ids_are_404(api: TestClient) -> None:
    assert api.post("/api/v1/studies/5/ask", json={"count": 1}).status_code == 404
    assert api.post("/api/v1/trials/5/tell", json={"value": 1.0}).status_code == 404
    assert api.post("/api/v1/trials/5/heartbeat", json={"worker_id": "w"}).status_code == 404
    assert api.get("/api/v1/trials/5").status_code == 404


def test_oversized_body_is_413(api: TestClient) -> None:
    body = copy.deepcopy(BOX_STUDY) | {"metadata": {"blob": "x" * 2_000_000}}
    response = api.post("/api/v1/studies", json=body)
    assert response.status_code == 413
    assert api.get("/api/v1/studies").json() == []


def test_stop_study_refuses_asks(api: TestClient) -> None:
    study = create(api)
    stopped = api.post(f"/api/v1/studies/{study['id']}/stop")
    assert stopped.json()["state"] == "stopped"
    assert api.post(f"/api/v1/studies/{study['id']}/ask", json={"count": 1}).status_code == 409


@pytest.mark.parametrize(
    "change",
    [
        {"metadata": {"note": "\ud800"}},
        {"metadata": {"\ud800": 1}},
        {"metadata": {"note": "a\x00b"}},
        {"proposer": {"name": "random", "options": {"x": ["\udfff"]}}},
    ],
)
def test_unstorable_text_is_422_not_500(api: TestClient, change: dict[str, Any]) -> None:
    """Regression: a lone surrogate in metadata answered 500 (found by load testing)."""
    body = json.dumps(copy.deepcopy(BOX_STUDY) | change)  # json escapes the surrogate
    response = api.post(
        "/api/v1/studies", content=body, headers={"Content-Type": "application/json"}
    )
    assert response.status_code == 422, response.text
    assert api.get("/api/v1/studies").json() == []


def test_unstorable_metric_name_is_422(api: TestClient) -> None:
    study = create(api)
    (trial,) = ask(api, study["id"])
    body = json.dumps({"value": 1.0, "metrics": {"\ud800": 1.0}})
    response = api.post(
        f"/api/v1/trials/{trial['id']}/tell",
        content=body,
        headers={"Content-Type": "application/json"},
    )
    assert response.status_code == 422
