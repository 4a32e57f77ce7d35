"""Trials handed to a study (``POST /studies/{id}/trials``) against a real server, on
SQLite and PostgreSQL: enqueued ones are handed out first, exactly once, also to
concurrent asks; evaluated ones warm-start the model; bad ones store nothing."""

from __future__ import annotations

import threading
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

import httpx
import pytest
import yaml

from adclient.testing.servers import ServerProcess, make_token

pytestmark = [pytest.mark.e2e, pytest.mark.xdist_group("enqueue")]
"""One xdist worker runs the module: the tests on ``shared_server`` share its two servers."""

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"

SPACE = {
    "type": "box",
    "params": [
        {"name": "x", "low": 0.0, "high": 1.0},
        {"name": "n", "type": "int", "low": 1, "high": 9},
        {"name": "c", "type": "categorical", "choices": ["a", "b", "c"]},
    ],
}


def study(http: httpx.Client, **fields: Any) -> dict[str, Any]:
    body = {"name": "handed", "space": SPACE, "proposer": {"name": "random"}} | fields
    created = http.post("/api/v1/studies", json=body)
    assert created.status_code == 201, created.text
    return dict(created.json())


def params(i: int) -> dict[str, Any]:
    return {"x": i / 100, "n": 1 + i % 9, "c": "abc"[i % 3]}


def test_enqueued_trials_come_first_in_order_then_proposals(shared_server: ServerProcess) -> None:
    with httpx.Client(base_url=shared_server.url, timeout=30, verify=False) as http:
        sid = study(http)["id"]
        added = http.post(
            f"/api/v1/studies/{sid}/trials", json=[{"params": params(i)} for i in range(3)]
        )
        assert added.status_code == 201, added.text
        queued = added.json()
        assert [t["state"] for t in queued] == ["queued"] * 3
        assert [t["number"] for t in queued] == [0, 1, 2]
        assert [t["params"] for t in queued] == [params(i) for i in range(3)]
        assert {t["info"]["source"] for t in queued} == {"enqueued"}
        first = http.post(f"/api/v1/studies/{sid}/ask", json={"count": 2}).json()["trials"]
        assert [(t["id"], t["state"]) for t in first] == [
            (queued[0]["id"], "running"),
            (queued[1]["id"], "running"),
        ]
        second = http.post(f"/api/v1/studies/{sid}/ask", json={"count": 2}).json()["trials"]
        assert second[0]["id"] == queued[2]["id"] and second[0]["params"] == params(2)
        assert second[1]["number"] == 3 and second[1]["info"]["proposer"] == "random"
        assert isinstance(second[1]["params"]["n"], int) and second[1]["params"]["c"] in "abc"
        one = http.post(f"/api/v1/studies/{sid}/trials", json={"params": params(7)})
        assert one.status_code == 201 and one.json()["number"] == 4  # an object answers one
        listed = http.get(f"/api/v1/studies/{sid}/trials", params={"state": "queued"}).json()
        assert [t["id"] for t in listed] == [one.json()["id"]]


def test_concurrent_asks_take_each_enqueued_trial_once(shared_server: ServerProcess) -> None:
    n_queued, n_clients, asks_each = 24, 6, 6
    with httpx.Client(base_url=shared_server.url, timeout=30, verify=False) as http:
        sid = study(http)["id"]
        added = http.post(
            f"/api/v1/studies/{sid}/trials", json=[{"params": params(i)} for i in range(n_queued)]
        ).json()
    handed: list[dict[str, Any]] = []
    errors: list[str] = []
    guard = threading.Lock()

    def asker() -> None:
        with httpx.Client(base_url=shared_server.url, timeout=60, verify=False) as http:
            for _ in range(asks_each):
                answer = http.post(f"/api/v1/studies/{sid}/ask", json={"count": 1})
                with guard:
                    if answer.status_code != 200:
                        errors.append(answer.text)
                    else:
                        handed.extend(answer.json()["trials"])

    threads = [threading.Thread(target=asker) for _ in range(n_clients)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert errors == []
    ids = Counter(t["id"] for t in handed)
    assert max(ids.values()) == 1  # nothing handed out twice
    enqueued = {t["id"] for t in added}
    assert enqueued <= set(ids)  # every enqueued trial handed out
    assert len(ids) - len(enqueued) == n_clients * asks_each - n_queued  # the rest proposed
    with httpx.Client(base_url=shared_server.url, timeout=30, verify=False) as http:
        assert http.get(f"/api/v1/studies/{sid}").json()["n_trials"] == n_clients * asks_each


def test_evaluated_trials_warm_start_the_model(shared_server: ServerProcess) -> None:
    with httpx.Client(base_url=shared_server.url, timeout=60, verify=False) as http:
        sid = study(http, proposer={"name": "qei", "n_initial": 4}, direction="minimize")["id"]
        known = [{"params": params(i), "value": (i - 4) ** 2 / 10} for i in range(8)]
        known.append({"params": params(40), "state": "failed", "message": "fell over"})
        added = http.post(f"/api/v1/studies/{sid}/trials", json=known)
        assert added.status_code == 201, added.text
        assert {t["info"]["source"] for t in added.json()} == {"added"}
        info = http.get(f"/api/v1/studies/{sid}").json()
        assert (info["n_complete"], info["n_failed"], info["n_trials"]) == (8, 1, 9)
        assert info["best_value"] == 0.0 and info["best_trial_id"] == added.json()[4]["id"]
        asked = http.post(f"/api/v1/studies/{sid}/ask", json={"count": 1}).json()["trials"][0]
        # Eight observations are past n_initial: the model fits them (no space-filling start).
        assert asked["info"]["proposer"] == "qei" and "fallback" not in asked["info"].get(
            "method", ""
        )


def test_duplicates_are_kept_unless_skipped(shared_server: ServerProcess) -> None:
    with httpx.Client(base_url=shared_server.url, timeout=30, verify=False) as http:
        sid = study(http)["id"]
        url = f"/api/v1/studies/{sid}/trials"
        first = http.post(url, json={"params": params(5)}).json()
        again = http.post(url, json={"params": params(5)}).json()
        assert again["id"] != first["id"]
        skipped = http.post(
            url,
            json=[
                {"params": params(5), "skip_if_exists": True},
                {"params": params(6), "skip_if_exists": True},
            ],
        )
        assert skipped.status_code == 201
        assert skipped.json()[0]["id"] == first["id"] and skipped.json()[1]["number"] == 2
        # A repeat within one body is the same trial too.
        twice = http.post(
            url, json=[{"params": params(8), "skip_if_exists": True} for _ in range(2)]
        ).json()
        assert twice[0]["id"] == twice[1]["id"] and twice[0]["number"] == 3
        # A failed evaluation does not count as existing: the params are tried again.
        failed = http.post(url, json={"params": params(7), "state": "failed"}).json()
        retried = http.post(url, json={"params": params(7), "skip_if_exists": True}).json()
        assert retried["id"] != failed["id"] and retried["state"] == "queued"


@pytest.mark.parametrize(
    ("body", "named"),
    [
        ({"params": {"x": 1.5, "n": 3, "c": "a"}}, "trial.params: param 'x': 1.5 is outside"),
        ({"params": {"x": 0.5, "n": 3.5, "c": "a"}}, "param 'n': 3.5 is not an integer"),
        ({"params": {"x": 0.5, "n": 3, "c": "z"}}, "param 'c': 'z' is not one of its choices"),
        ({"params": {"x": 0.5, "n": 3}}, "param 'c' is missing"),
        ({"params": {"x": 0.5, "n": 3, "c": "a", "y": 1}}, "unknown param 'y'"),
        # an integer past the float range (a 500 from math.isfinite's OverflowError)
        (
            {"params": {"x": 10**400, "n": 3, "c": "a"}},
            f"param 'x': {'1' + '0' * 59}... (401 characters) is not a finite number",
        ),
        ({"params": {"x": 0.5, "n": 10**400, "c": "a"}}, "param 'n': 1000"),
        (
            {"params": {"x": 0.5, "n": 3, "c": "a"}, "state": "queued", "value": 1.0},
            "carries no value",
        ),
        ({"params": {"x": 0.5, "n": 3, "c": "a"}, "state": "complete"}, "value is required"),
        ({"params": {"x": 0.5, "n": 3, "c": "a"}, "value": "nan"}, "value"),
        ({"param": {"x": 0.5}}, "trial.params: Field required"),
        ([{"params": params(1)}, {"params": {"x": -1, "n": 3, "c": "a"}}], "trials[1].params"),
        ([], "trials: List should have at least 1 item"),
    ],
)
def test_a_bad_trial_is_named_and_nothing_is_stored(
    shared_server: ServerProcess, body: Any, named: str
) -> None:
    with httpx.Client(base_url=shared_server.url, timeout=30, verify=False) as http:
        sid = study(http)["id"]
        answer = http.post(f"/api/v1/studies/{sid}/trials", json=body)
        assert answer.status_code == 422, answer.text
        assert named in answer.json()["detail"]
        assert http.get(f"/api/v1/studies/{sid}").json()["n_trials"] == 0


def test_no_room_or_a_stopped_study_is_409_and_stores_nothing(shared_server: ServerProcess) -> None:
    with httpx.Client(base_url=shared_server.url, timeout=30, verify=False) as http:
        sid = study(http, max_trials=3)["id"]
        url = f"/api/v1/studies/{sid}/trials"
        full = http.post(url, json=[{"params": params(i)} for i in range(4)])
        assert full.status_code == 409 and "max_trials=3" in full.json()["detail"]
        assert http.get(f"/api/v1/studies/{sid}").json()["n_trials"] == 0
        assert http.post(url, json=[{"params": params(i)} for i in range(3)]).status_code == 201
        # Enqueued trials are the study's trials: an ask takes them although the study is full.
        assert len(http.post(f"/api/v1/studies/{sid}/ask", json={"count": 3}).json()["trials"]) == 3
        other = study(http)["id"]
        assert http.post(f"/api/v1/studies/{other}/stop", json={}).status_code == 200
        stopped = http.post(f"/api/v1/studies/{other}/trials", json={"params": params(1)})
        assert stopped.status_code == 409


def test_a_managed_study_leases_its_enqueued_trials_first(shared_server: ServerProcess) -> None:
    lease = {"worker_id": "w", "tasks": ["enqueued-first"]}  # this study's jobs alone
    with httpx.Client(base_url=shared_server.url, timeout=30, verify=False) as http:
        sid = study(http, task={"name": "enqueued-first", "external": True}, max_trials=5)["id"]
        queued = http.post(f"/api/v1/studies/{sid}/trials", json={"params": params(3)}).json()
        job = http.post("/api/v1/jobs/lease", json=lease).json()
        assert job["trial_id"] == queued["id"] and job["params"] == params(3)
        assert job["attempt"] == 1
        after = http.post("/api/v1/jobs/lease", json=lease).json()
        assert after["trial_id"] != queued["id"]  # then proposals


def test_only_the_owner_hands_trials_to_a_study(
    server_factory: Callable[..., ServerProcess],
) -> None:
    server = server_factory(AD_AUTH="true")

    def as_token(role: str) -> httpx.Client:
        token = make_token(server, role)
        return httpx.Client(
            base_url=server.url,
            headers={"Authorization": f"Bearer {token}", "X-Activedesign-Client": "test"},
            timeout=30,
            verify=False,
        )

    with as_token("user") as owner, as_token("user") as other, as_token("worker") as worker:
        sid = study(owner)["id"]
        url = f"/api/v1/studies/{sid}/trials"
        assert other.post(url, json={"params": params(1)}).status_code == 403
        assert worker.post(url, json={"params": params(1)}).status_code == 403
        assert owner.post(url, json={"params": params(1)}).status_code == 201
        assert owner.get(f"/api/v1/studies/{sid}").json()["n_trials"] == 1


def test_a_design_is_enqueued_by_its_specs(shared_server: ServerProcess) -> None:
    body = yaml.safe_load((EXAMPLES / "multi-structure.yaml").read_text())
    body.pop("task")
    body |= {"proposer": {"name": "random"}, "max_trials": 8}
    with httpx.Client(base_url=shared_server.url, timeout=30, verify=False) as http:
        sid = http.post("/api/v1/studies", json=body).json()["id"]
        asked = http.post(f"/api/v1/studies/{sid}/ask", json={"count": 1}).json()["trials"][0]
        url = f"/api/v1/studies/{sid}/trials"
        again = http.post(url, json={"params": asked["params"]})
        assert again.status_code == 201, again.text
        # The same design, decoded back (its vector may differ: several encode one design).
        assert again.json()["params"] == asked["params"]
        wrong = dict(asked["params"], structure="a-e")
        refused = http.post(url, json={"params": wrong})
        assert refused.status_code == 422 and "is not structure_index" in refused.json()["detail"]
        # derived params (the axis its angles give, the root) are checked, not replaced
        axis = asked["params"]["b.joint.axis"]
        turned = [axis[1], axis[2], axis[0]]
        for key, value in (("b.joint.axis", turned), ("root", "b")):
            refused = http.post(url, json={"params": dict(asked["params"], **{key: value})})
            assert refused.status_code == 422, refused.text
            assert f"params: {key} = {value!r} is not this design's" in refused.json()["detail"]
        nudged = [component + 1e-12 for component in axis]
        assert (
            http.post(
                url, json={"params": dict(asked["params"], **{"b.joint.axis": nudged})}
            ).status_code
            == 201
        )
        # a spec's value that float() refused with TypeError or OverflowError (a 500)
        for bad in (10**400, [0.5], {"a": 1}):
            refused = http.post(
                url, json={"params": dict(asked["params"], **{"b.joint.axis_theta": bad})}
            )
            assert refused.status_code == 422, refused.text
            assert "spec 'b.joint.axis_theta' is not a finite number" in refused.json()["detail"]
        missing = {k: v for k, v in asked["params"].items() if k != "b.joint.axis_phi"}
        refused = http.post(url, json={"params": missing})
        assert (
            refused.status_code == 422
            and "'b.joint.axis_phi' is missing" in refused.json()["detail"]
        )
        assert http.get(f"/api/v1/studies/{sid}").json()["n_trials"] == 3
