"""The dashboard's own reads: chart columns as a delta, artifact names for a table page,
and the page itself served at ``/``."""

from __future__ import annotations

from typing import Any

from fastapi.testclient import TestClient

from adservice.app import STATIC_DIR as STATIC
from tests.service.conftest import BOX_STUDY


def make_study(api: TestClient, asked: int) -> tuple[int, list[dict[str, Any]]]:
    study = api.post("/api/v1/studies", json=BOX_STUDY).json()
    trials = api.post(f"/api/v1/studies/{study['id']}/ask", json={"count": asked}).json()["trials"]
    return study["id"], trials


def test_full_series_matches_the_plain_series(api: TestClient) -> None:
    study_id, trials = make_study(api, asked=5)
    api.post(f"/api/v1/trials/{trials[0]['id']}/tell", json={"value": 1.5})
    api.post(f"/api/v1/trials/{trials[1]['id']}/tell", json={"state": "failed"})
    full = api.get(f"/api/v1/dashboard/studies/{study_id}/series").json()
    assert full == api.get(f"/api/v1/studies/{study_id}/series").json()
    assert full["number"] == [0, 1, 2, 3, 4]
    assert full["state"][:3] == ["complete", "failed", "running"]
    assert full["value"][:2] == [1.5, None]
    assert set(full["params"]) == {"x", "y"}
    assert full["params"]["x"][0] == trials[0]["params"]["x"]


def test_series_delta_is_new_trials_and_the_listed_open_ones(api: TestClient) -> None:
    study_id, trials = make_study(api, asked=4)
    api.post(f"/api/v1/trials/{trials[2]['id']}/tell", json={"value": 3.0})
    api.post(f"/api/v1/studies/{study_id}/ask", json={"count": 2})
    url = f"/api/v1/dashboard/studies/{study_id}/series"
    delta = api.get(url, params={"after": 4, "numbers": "1,2"}).json()
    assert delta["number"] == [1, 2, 4, 5]
    assert delta["state"] == ["running", "complete", "running", "running"]
    assert delta["value"] == [None, 3.0, None, None]
    assert len(delta["params"]["y"]) == 4
    nothing = api.get(url, params={"after": 6}).json()
    assert nothing == {
        "number": [],
        "state": [],
        "value": [],
        "params": {},
        "values": None,  # a study of one objective
        "feasible": None,  # without constraints
        "next": None,
    }


def test_series_pages_follow_next_and_keep_the_listed_open_ones(api: TestClient) -> None:
    study_id, trials = make_study(api, asked=7)
    api.post(f"/api/v1/trials/{trials[1]['id']}/tell", json={"value": 2.0})
    url = f"/api/v1/dashboard/studies/{study_id}/series"
    first = api.get(url, params={"after": 5, "numbers": "1,3", "limit": 2}).json()
    assert first["number"] == [1, 3] and first["next"] == 4
    second = api.get(url, params={"after": first["next"], "limit": 3}).json()
    assert second["number"] == [4, 5, 6] and second["next"] is None
    plain = f"/api/v1/studies/{study_id}/series"
    pages, after = [], 0
    while after is not None:
        page = api.get(plain, params={"after": after, "limit": 3}).json()
        pages.append(page["number"])
        after = page["next"]
    assert pages == [[0, 1, 2], [3, 4, 5], [6]]
    assert api.get(plain, params={"limit": 5001}).status_code == 422


def test_series_delta_refuses_bad_lists_and_unknown_studies(api: TestClient) -> None:
    study_id, _ = make_study(api, asked=1)
    url = f"/api/v1/dashboard/studies/{study_id}/series"
    bad = api.get(url, params={"numbers": "1,two"})
    assert bad.status_code == 422 and "numbers" in bad.json()["detail"]
    assert api.get(url, params={"numbers": "-3"}).status_code == 422
    assert api.get(url, params={"numbers": ",".join(["1"] * 1001)}).status_code == 422
    assert api.get(url, params={"after": -1}).status_code == 422
    assert api.get("/api/v1/dashboard/studies/999/series").status_code == 404


def test_artifact_names_for_a_page_of_trials(api: TestClient) -> None:
    study_id, trials = make_study(api, asked=3)
    first, second, third = (trial["id"] for trial in trials)
    for name in ("robot.png", "curve.json"):
        put = api.put(f"/api/v1/trials/{first}/artifacts/{name}", content=b"x")
        assert put.status_code == 201, put.text
    api.put(f"/api/v1/trials/{third}/artifacts/robot.urdf", content=b"<robot/>")
    other_id, other_trials = make_study(api, asked=1)
    url = f"/api/v1/dashboard/studies/{study_id}/artifacts"
    names = api.get(url, params={"trial_ids": f"{first},{second},{third}"}).json()
    assert names == {
        str(first): ["curve.json", "robot.png"],
        str(second): [],
        str(third): ["robot.urdf"],
    }
    # A trial of another study lists nothing here.
    foreign = other_trials[0]["id"]
    api.put(f"/api/v1/trials/{foreign}/artifacts/robot.png", content=b"x")
    assert api.get(url, params={"trial_ids": str(foreign)}).json() == {str(foreign): []}
    assert api.get(url).json() == {}
    assert other_id != study_id


def test_the_page_is_served_at_the_root(api: TestClient) -> None:
    page = api.get("/")
    assert page.status_code == 200 and "text/html" in page.headers["content-type"]
    assert 'src="js/app.js"' in page.text and "ad_token" not in page.text
    assert api.get("/dashboard.css").status_code == 200
    # Every module (one per panel) and the vendored 3D bundle, as JavaScript: a browser
    # runs an ES module only when it comes with a JavaScript type.
    modules = sorted(path.relative_to(STATIC).as_posix() for path in STATIC.glob("js/*.js"))
    assert {"js/app.js", "js/study.js", "js/robot-view.js"} <= set(modules)
    for asset in [*modules, "vendor/three-urdf.js"]:
        response = api.get(f"/{asset}")
        assert response.status_code == 200, asset
        assert "javascript" in response.headers["content-type"], asset
