"""A study's ``searched_params``: the keys of its trials' params that the search chooses,
which the dashboard's best design shows (issue 40)."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from fastapi.testclient import TestClient

from tests.service.conftest import BOX_STUDY

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def example(name: str) -> dict:
    body = yaml.safe_load((EXAMPLES / name).read_text())
    if body["space"]["type"] == "template":
        body["space"]["template"] = (EXAMPLES / body["space"]["template"]).read_text()
    return body


@pytest.mark.parametrize("database", ["sqlite"])
def test_a_study_names_the_params_it_searches(api: TestClient) -> None:
    """The quadruped of bought parts searches one leg (the others copy it), its servos
    and its axes: 6 of its best design's 100-odd params. A box or template study
    searches every param."""
    study = api.post("/api/v1/studies", json=example("quadruped-budget.yaml")).json()
    assert study["searched_params"] == [
        "front_left.joint.axis",
        "front_left.joint.choice",
        "front_left.length",
        "front_left_shin.joint.axis",
        "front_left_shin.joint.choice",
        "front_left_shin.length",
    ]
    (trial,) = api.post(f"/api/v1/studies/{study['id']}/ask", json={}).json()["trials"]
    assert set(study["searched_params"]) < set(trial["params"])
    assert len(trial["params"]) > 100
    read = api.get(f"/api/v1/studies/{study['id']}").json()
    assert read["searched_params"] == study["searched_params"]
    listed = {item["id"]: item for item in api.get("/api/v1/studies").json()}
    assert listed[study["id"]]["searched_params"] == study["searched_params"]

    several = api.post("/api/v1/studies", json=example("multi-structure.yaml")).json()
    assert "structure" in several["searched_params"]

    box = api.post("/api/v1/studies", json=BOX_STUDY).json()
    assert box["searched_params"] == ["x", "y"]
    template = api.post("/api/v1/studies", json=example("template-arm.yaml")).json()
    assert template["searched_params"] == ["upper_length", "fore_length", "hand_radius"]
