"""Intermediate reports and pruned trials against a real ``adserver`` process: the
report contract (median and ASHA decisions on fixed sequences, repeats, 422, 409, 403,
a lease lost mid-report), pruned tells, counts and filters."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from typing import Any

import httpx
import pytest

from adclient.testing.servers import SDK_HEADERS, ServerProcess, make_token

pytestmark = [pytest.mark.e2e, pytest.mark.xdist_group("pruning")]
"""One xdist worker runs the module: the tests on ``shared_server`` share its two servers."""


def box_study(pruner: dict[str, Any] | None, **extra: Any) -> dict[str, Any]:
    body: dict[str, Any] = {
        "name": "pruned",
        "direction": "maximize",
        "space": {"type": "box", "params": [{"name": "x", "low": 0, "high": 1}]},
        "proposer": {"name": "random", "seed": 1},
        **extra,
    }
    if pruner is not None:
        body["pruner"] = pruner
    return body


@pytest.fixture
def http(shared_server: ServerProcess) -> Iterator[httpx.Client]:
    """The module's server: each test looks only at its own study."""
    with httpx.Client(
        base_url=shared_server.url, headers=SDK_HEADERS, timeout=30, verify=False
    ) as client:
        yield client


def create(http: httpx.Client, body: dict[str, Any]) -> dict[str, Any]:
    created = http.post("/api/v1/studies", json=body)
    assert created.status_code == 201, created.text
    return created.json()


def ask(http: httpx.Client, study: dict[str, Any]) -> int:
    asked = http.post(f"/api/v1/studies/{study['id']}/ask", json={"count": 1})
    assert asked.status_code == 200, asked.text
    return int(asked.json()["trials"][0]["id"])


def report(http: httpx.Client, trial: int, step: int, value: float, **extra: Any) -> bool:
    answer = http.post(
        f"/api/v1/trials/{trial}/report", json={"step": step, "value": value, **extra}
    )
    assert answer.status_code == 200, answer.text
    return bool(answer.json()["should_stop"])


def finish(http: httpx.Client, trial: int, curve: list[tuple[int, float]]) -> None:
    for step, value in curve:
        report(http, trial, step, value)
    told = http.post(f"/api/v1/trials/{trial}/tell", json={"value": curve[-1][1]})
    assert told.status_code == 200, told.text


def test_a_box_study_has_no_pruner_by_default(http: httpx.Client) -> None:
    study = create(http, box_study(None))
    assert study["pruner"]["name"] == "none" and study["n_pruned"] == 0
    trial = ask(http, study)
    assert report(http, trial, 1, -1e9) is False  # recorded, never stopped
    assert [p["value"] for p in http.get(f"/api/v1/trials/{trial}/reports").json()] == [-1e9]


def test_median_stops_a_trial_below_the_complete_trials_median(http: httpx.Client) -> None:
    pruner = {"name": "median", "options": {"n_startup_trials": 2, "n_warmup_steps": 1}}
    study = create(http, box_study(pruner))
    assert study["pruner"]["options"]["interval_steps"] == 1  # defaults filled in
    early = ask(http, study)
    assert report(http, early, 2, -100.0) is False  # no complete trial yet
    finish(http, ask(http, study), [(1, 1.0), (2, 2.0), (3, 3.0)])
    assert report(http, early, 3, -100.0) is False  # one complete trial: still starting up
    finish(http, ask(http, study), [(1, 3.0), (2, 4.0), (3, 5.0)])
    # Median at step 2 of the complete trials: (2 + 4) / 2 = 3.
    bad, good, warm = ask(http, study), ask(http, study), ask(http, study)
    assert report(http, bad, 2, 2.9) is True
    assert report(http, good, 2, 4.5) is False
    assert report(http, warm, 0, -50.0) is False  # within the warm-up steps
    assert report(http, warm, 2, -50.0) is True
    # Its best so far counts, not its last value: a dip below step 3's median (4) goes
    # on after 4.5 at step 2.
    assert report(http, good, 3, 0.0) is False
    assert report(http, bad, 3, 3.5) is True  # best 3.5 < 4


def test_median_minimizing_orients_values(http: httpx.Client) -> None:
    pruner = {"name": "median", "options": {"n_startup_trials": 1}}
    study = create(http, box_study(pruner, direction="minimize"))
    finish(http, ask(http, study), [(5, 1.0)])
    trial = ask(http, study)
    assert report(http, trial, 5, 0.5) is False
    other = ask(http, study)
    assert report(http, other, 5, 1.5) is True


def test_asha_promotes_the_top_fraction_at_each_rung(http: httpx.Client) -> None:
    pruner = {"name": "asha", "options": {"min_resource": 10, "reduction_factor": 2}}
    study = create(http, box_study(pruner))
    a, b, c = ask(http, study), ask(http, study), ask(http, study)
    assert report(http, a, 5, 0.0) is False  # below the first rung: no decision
    assert report(http, a, 10, 1.0) is False  # alone at rung 10: promoted
    assert report(http, b, 10, 0.5) is True  # [1.0, 0.5]: top half is 1.0 only
    assert report(http, c, 12, 2.0) is False  # crosses rung 10 at 12 with the best value
    assert report(http, a, 20, 1.5) is False  # alone at rung 20
    assert report(http, c, 25, 1.0) is True  # [1.5, 1.0] at rung 20
    # A trial ended by its pruner still competes with what it reached: b's 0.5 counts.
    d = ask(http, study)
    # At rung 10: [2.0, 1.0, 0.75, 0.5]; 4 // 2 - 1 = 1, so d needs the 2nd best, 1.0.
    assert report(http, d, 10, 0.75) is True
    e = ask(http, study)
    # Five values: 5 // 2 - 1 = 1 again; e's 1.0 ties the 2nd best and goes on.
    assert report(http, e, 10, 1.0) is False


def test_report_contract_errors_and_repeats(http: httpx.Client) -> None:
    study = create(http, box_study({"name": "median", "options": {"n_startup_trials": 0}}))
    trial = ask(http, study)
    assert report(http, trial, 3, 0.25) is False
    assert report(http, trial, 3, 0.25) is False  # an identical repeat is harmless
    curve = http.get(f"/api/v1/trials/{trial}/reports").json()
    assert [(p["step"], p["value"]) for p in curve] == [(3, 0.25)]
    for bad in ('{"step": 1, "value": NaN}', '{"step": 1, "value": 1e999}'):
        refused = http.post(
            f"/api/v1/trials/{trial}/report",
            content=bad,
            headers={"Content-Type": "application/json"},
        )
        assert refused.status_code == 422, refused.text
    for body in ({"step": -1, "value": 1.0}, {"value": 1.0}, {"step": 1, "value": "x"}):
        assert http.post(f"/api/v1/trials/{trial}/report", json=body).status_code == 422
    missing = http.post("/api/v1/trials/999999/report", json={"step": 1, "value": 1})
    assert missing.status_code == 404
    told = http.post(f"/api/v1/trials/{trial}/tell", json={"value": 0.25})
    assert told.status_code == 200
    late = http.post(f"/api/v1/trials/{trial}/report", json={"step": 4, "value": 1.0})
    assert late.status_code == 409 and late.json()["error"] == "conflict"
    assert len(http.get(f"/api/v1/trials/{trial}/reports").json()) == 1
    bad_pruner = http.post(
        "/api/v1/studies", json=box_study({"name": "asha", "options": {"reduction_factor": 1}})
    )
    assert bad_pruner.status_code == 422
    unknown = http.post("/api/v1/studies", json=box_study({"name": "hyperband"}))
    assert unknown.status_code == 422


def test_pruned_tells_count_filter_and_end_the_study(http: httpx.Client) -> None:
    study = create(http, box_study({"name": "none"}, max_trials=3))
    pruned, valued, done = ask(http, study), ask(http, study), ask(http, study)
    report(http, pruned, 1, 0.5)
    report(http, pruned, 2, 0.75)
    told = http.post(f"/api/v1/trials/{pruned}/tell", json={"state": "pruned"})
    assert told.status_code == 200, told.text
    assert told.json()["state"] == "pruned" and told.json()["value"] == 0.75  # last report
    again = http.post(f"/api/v1/trials/{pruned}/tell", json={"state": "pruned"})
    assert again.status_code == 200  # a repeat is harmless
    contradicting = http.post(f"/api/v1/trials/{pruned}/tell", json={"value": 9.0})
    assert contradicting.status_code == 409
    with_value = http.post(f"/api/v1/trials/{valued}/tell", json={"state": "pruned", "value": 2})
    assert with_value.status_code == 200 and with_value.json()["value"] == 2.0
    current = http.get(f"/api/v1/studies/{study['id']}").json()
    assert (current["n_pruned"], current["n_complete"], current["state"]) == (2, 0, "running")
    assert current["best_value"] is None  # a pruned trial is never the best
    listed = http.get(f"/api/v1/studies/{study['id']}/trials", params={"state": "pruned"})
    assert sorted(t["id"] for t in listed.json()) == sorted([pruned, valued])
    assert listed.headers["X-Total-Count"] == "2"
    assert http.post(f"/api/v1/trials/{done}/tell", json={"value": 1.0}).status_code == 200
    final = http.get(f"/api/v1/studies/{study['id']}").json()
    assert final["state"] == "complete" and final["best_trial_id"] == done
    series = http.get(f"/api/v1/studies/{study['id']}/series").json()
    assert series["state"].count("pruned") == 2


@pytest.fixture
def secured(server_factory: Callable[..., ServerProcess]) -> ServerProcess:
    return server_factory(AD_AUTH="true", AD_LEASE_SECONDS="1")


def client(server: ServerProcess, token: str) -> httpx.Client:
    headers = {"Authorization": f"Bearer {token}", **SDK_HEADERS}
    return httpx.Client(base_url=server.url, headers=headers, timeout=30, verify=False)


def test_only_the_lease_holder_reports_and_a_lost_lease_is_409(secured: ServerProcess) -> None:
    user, worker, other = (make_token(secured, role) for role in ("user", "worker", "worker"))
    managed = box_study(
        {"name": "median", "options": {"n_startup_trials": 0}},
        task={"name": "noop", "external": True},
        max_trials=2,
    )
    with (
        client(secured, user) as as_user,
        client(secured, worker) as w1,
        client(secured, worker) as w2,
        client(secured, other) as stranger,
    ):
        create(as_user, managed)
        job = w1.post("/api/v1/jobs/lease", json={"worker_id": "w1"}).json()
        url = f"/api/v1/trials/{job['trial_id']}/report"
        ok = w1.post(url, json={"step": 1, "value": 1.0, "worker_id": "w1"})
        assert ok.status_code == 200 and ok.json() == {"should_stop": False, "pause": False}
        stolen = stranger.post(url, json={"step": 1, "value": 1.0, "worker_id": "w1"})
        assert stolen.status_code == 403, stolen.text
        nameless = w1.post(url, json={"step": 2, "value": 1.0})
        assert nameless.status_code == 403
        owner = as_user.post(url, json={"step": 2, "value": 1.0})
        assert owner.status_code == 403  # a worker holds it
        assert w1.post(url, json={"step": 1, "value": 1.0, "worker_id": "other"}).status_code == 409
        # The lease runs out (1 s, no heartbeat), the trial goes back to the queue
        # and w2 (the same fleet token) takes it: w1's next report is told it lost
        # the lease (with another token it would be 403, as a heartbeat is).
        deadline = time.monotonic() + 20
        taken = None
        while time.monotonic() < deadline:
            leased = w2.post("/api/v1/jobs/lease", json={"worker_id": "w2"})
            if leased.status_code == 200 and leased.json()["trial_id"] == job["trial_id"]:
                taken = leased.json()
                break
            time.sleep(0.3)
        assert taken is not None and taken["attempt"] == 2
        lost = w1.post(url, json={"step": 2, "value": 5.0, "worker_id": "w1"})
        assert lost.status_code == 409 and lost.json()["error"] == "lease_lost"
        again = w2.post(url, json={"step": 1, "value": 0.5, "worker_id": "w2"})
        assert again.status_code == 200
        curve = w2.get(f"/api/v1/trials/{job['trial_id']}/reports").json()
        assert [(p["step"], p["value"]) for p in curve] == [(1, 0.5)]  # attempt 2's
