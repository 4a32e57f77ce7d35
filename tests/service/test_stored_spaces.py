"""A rule a new design space must meet, added after studies were stored under looser
ones, refuses new studies only: a stored study that breaks it still reads, lists and
proposes (``DesignSpace.check_at_creation``). Were it checked whenever a space is read,
one such study would fail ``GET /api/v1/studies`` for every user."""

from __future__ import annotations

import copy
from typing import Any

import pytest
from fastapi.testclient import TestClient

from tests.failing_proposals import update_study

ARM: dict[str, Any] = {
    "type": "design",
    "parts": {"link": {"length": {"low": 0.2, "high": 0.6}, "radius": 0.04, "mass": 1.0}},
    "joint": {"effort": {"low": 1.0, "high": 20.0}},
    "instances": [
        {"name": "a", "part": "link"},
        {"name": "b", "part": "link"},
        {"name": "c", "part": "link", "joint_type": "fixed"},
    ],
    "structures": [[["a", "b"], ["b", "c"]]],
}
PLACEHOLDER = [{"terms": {"c.joint.effort": 1.0}, "op": "<=", "bound": 5.0}]
"""A budget on a fixed joint's effort, which no design changes: refused since issue 36."""


def study_body(name: str, space: dict[str, Any]) -> dict[str, Any]:
    return {
        "name": name,
        "direction": "maximize",
        "space": space,
        "proposer": {"name": "random", "seed": 1},
    }


@pytest.mark.parametrize(
    "change",
    [
        pytest.param({"spec_constraints": PLACEHOLDER}, id="placeholder constraint"),
        pytest.param(
            {
                "catalogues": {"servos": {"s1": {"effort": 2.0}, "s2": {"effort": 4.0}}},
                "joint": {"choose": "servos"},
                "instances": [
                    {"name": "a", "part": "link"},
                    {"name": "b", "part": "link", "joint_overrides": {"effort": 3.0}},
                ],
                "structures": [[["a", "b"]]],
            },
            id="override of a chosen component's spec",
        ),
    ],
)
def test_a_stored_space_under_an_older_rule_still_loads_and_a_new_one_is_refused(
    api: TestClient, database_url: str, change: dict[str, Any]
) -> None:
    space = {**copy.deepcopy(ARM), **change}
    refused = api.post("/api/v1/studies", json=study_body("new", space))
    assert refused.status_code == 422, refused.text
    assert api.get("/api/v1/studies").json() == []

    # the same space as a server before the rule stored it
    plain = {key: value for key, value in space.items() if key != "spec_constraints"}
    if "catalogues" in change:
        plain["instances"] = [{"name": "a", "part": "link"}, {"name": "b", "part": "link"}]
    created = api.post("/api/v1/studies", json=study_body("stored", plain))
    assert created.status_code == 201, created.text
    study_id = created.json()["id"]
    stored = {**created.json()["space"], **change}
    update_study(database_url, study_id, space=stored)

    listed = api.get("/api/v1/studies")
    assert listed.status_code == 200, listed.text
    assert [study["id"] for study in listed.json()] == [study_id]
    read = api.get(f"/api/v1/studies/{study_id}")
    assert read.status_code == 200, read.text
    names = [instance["name"] for instance in read.json()["space"]["instances"]]
    assert names == [instance["name"] for instance in stored["instances"]]
    asked = api.post(f"/api/v1/studies/{study_id}/ask", json={"count": 1})
    assert asked.status_code == 200, asked.text
