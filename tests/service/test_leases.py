"""Leases for workers: one holder at a time, heartbeats, expiry, retries, lost leases."""

from __future__ import annotations

import copy
import time
from typing import Any

import pytest
import sqlalchemy as sa
from fastapi.testclient import TestClient

from adclient.schemas import MAX_WORKER_PAGE
from adclient.testing.servers import SDK_HEADERS
from adservice.app import create_app
from adservice.repository import promotion
from adservice.settings import Settings
from tests.service.conftest import BOX_STUDY, LOCAL


def managed(
    api: TestClient, max_trials: int = 4, max_attempts: int = 3, task: str = "noop"
) -> dict[str, Any]:
    body = copy.deepcopy(BOX_STUDY) | {
        "task": {"name": task, "external": True},
        "max_trials": max_trials,
        "max_attempts": max_attempts,
    }
    response = api.post("/api/v1/studies", json=body)
    assert response.status_code == 201, response.text
    return response.json()


def lease(api: TestClient, worker: str, tasks: list[str] | None = None) -> dict[str, Any] | None:
    body: dict[str, Any] = {"worker_id": worker}
    if tasks is not None:
        body["tasks"] = tasks
    response = api.post("/api/v1/jobs/lease", json=body)
    assert response.status_code in (200, 204), response.text
    return response.json() if response.status_code == 200 else None


def test_no_work_is_204(api: TestClient) -> None:
    assert lease(api, "w1") is None
    api.post("/api/v1/studies", json=BOX_STUDY)  # not managed: never leased
    assert lease(api, "w1") is None


def test_lease_carries_the_job_and_trials_are_distinct(api: TestClient) -> None:
    study = managed(api, max_trials=2)
    first, second = lease(api, "w1"), lease(api, "w2")
    assert first is not None and second is not None
    assert first["trial_id"] != second["trial_id"]
    assert first["task"]["name"] == "noop" and first["space"]["type"] == "box"
    assert first["study_id"] == study["id"] and first["attempt"] == 1
    assert first["lease_expires_at"]
    assert lease(api, "w3") is None  # max_trials reached, both running
    told = api.post(
        f"/api/v1/trials/{first['trial_id']}/tell",
        json={"value": 1.0, "worker_id": "w1", "metrics": {"steps": 10}},
    )
    assert told.status_code == 200 and told.json()["metrics"] == {"steps": 10.0}
    workers = api.get(f"/api/v1/studies/{study['id']}/workers").json()
    assert {w["worker_id"]: w["jobs_done"] for w in workers} == {"w1": 1, "w2": 0}


def test_a_worker_leases_only_the_tasks_it_names(api: TestClient) -> None:
    welding = managed(api, max_trials=2, task="welding")
    painting = managed(api, max_trials=1, task="painting")
    assert lease(api, "w1", tasks=[]) is None
    assert lease(api, "w1", tasks=["stand-up"]) is None
    first = lease(api, "painter", tasks=["painting", "stand-up"])
    assert first is not None and first["study_id"] == painting["id"]
    assert lease(api, "painter", tasks=["painting"]) is None  # its study is full
    released = api.post(
        f"/api/v1/trials/{first['trial_id']}/release", json={"worker_id": "painter"}
    )
    assert released.status_code == 200  # a queued painting trial, older than any welding one
    welder = lease(api, "welder", tasks=["welding"])
    assert welder is not None and welder["study_id"] == welding["id"]
    anyone = lease(api, "anyone")  # no list: any task, the queued trial first
    assert anyone is not None and anyone["trial_id"] == first["trial_id"]
    refused = api.post("/api/v1/jobs/lease", json={"worker_id": "w", "tasks": ["bad name!"]})
    assert refused.status_code == 422 and "tasks" in refused.json()["detail"]


def test_only_the_holder_may_tell_or_heartbeat(api: TestClient) -> None:
    managed(api)
    job = lease(api, "w1")
    assert job is not None
    trial_url = f"/api/v1/trials/{job['trial_id']}"
    beat = api.post(f"{trial_url}/heartbeat", json={"worker_id": "w1"})
    assert beat.status_code == 200 and beat.json()["lease_expires_at"] >= job["lease_expires_at"]
    assert api.post(f"{trial_url}/heartbeat", json={"worker_id": "w2"}).status_code == 409
    stolen = api.post(f"{trial_url}/tell", json={"value": 1.0, "worker_id": "w2"})
    assert stolen.status_code == 409 and stolen.json()["error"] == "lease_lost"
    assert api.get(trial_url).json()["state"] == "running"


def test_the_holder_releases_a_trial_back_to_the_queue_without_spending_an_attempt(
    api: TestClient,
) -> None:
    study = managed(api, max_trials=1, max_attempts=1)
    job = lease(api, "leaving")
    assert job is not None
    trial_url = f"/api/v1/trials/{job['trial_id']}"
    refused = api.post(f"{trial_url}/release", json={"worker_id": "other"})
    assert refused.status_code == 409 and refused.json()["error"] == "lease_lost"
    released = api.post(f"{trial_url}/release", json={"worker_id": "leaving"})
    assert released.status_code == 200, released.text
    assert released.json()["state"] == "queued" and released.json()["attempts"] == 0
    assert api.post(f"{trial_url}/release", json={"worker_id": "leaving"}).status_code == 409
    again = lease(api, "staying")  # at once, not after the lease would have expired
    assert again is not None and again["trial_id"] == job["trial_id"] and again["attempt"] == 1
    late = api.post(f"{trial_url}/tell", json={"value": 1.0, "worker_id": "leaving"})
    assert late.status_code == 409
    ok = api.post(f"{trial_url}/tell", json={"value": 2.0, "worker_id": "staying"})
    assert ok.status_code == 200 and ok.json()["attempts"] == 1
    workers = api.get(f"/api/v1/studies/{study['id']}/workers").json()
    assert [w["worker_id"] for w in workers] == ["staying"]  # the leaver holds nothing


@pytest.fixture
def quick_backoff_api(settings: Settings) -> Any:
    quick = settings.model_copy(update={"proposal_backoff_seconds": 0.05})
    with TestClient(create_app(quick), base_url=LOCAL, headers=SDK_HEADERS) as client:
        yield client


def test_a_lease_whose_job_cannot_be_read_gives_the_trial_back(
    quick_backoff_api: TestClient,
) -> None:
    """The lease's write commits before its job is read (here a shared study's current
    version). When that read fails (the database drops the connection), the trial is back
    in the queue at once with its attempt not counted, and the failure is recorded on the
    study, which leases skip for its backoff: on both paths, a freshly proposed trial and
    a queued one. Before, a proposed trial's lease answered 500 and the trial stayed
    leased to a worker that never got its job until the lease expired, spending an
    attempt."""
    api = quick_backoff_api
    body = copy.deepcopy(BOX_STUDY) | {
        "task": {"name": "noop", "external": True, "transfer": "shared"},
        "max_trials": 1,
        "max_attempts": 1,
    }
    study = api.post("/api/v1/studies", json=body).json()
    engine = api.app.state.db.engine  # type: ignore[attr-defined]
    failing = {"on": True}

    def drop_shared_reads(conn: Any, cursor: Any, statement: str, *args: Any) -> None:
        read = statement.lstrip().upper().startswith("SELECT")
        if failing["on"] and read and "shared_controllers" in statement:
            raise sa.exc.OperationalError(statement, None, Exception("connection dropped"))

    sa.event.listen(engine, "before_cursor_execute", drop_shared_reads)
    try:
        for path, failures in (("proposed", 1), ("queued", 2)):
            time.sleep(0.25)  # past the study's backoff (0.05 s, then 0.1 s)
            assert lease(api, "w1") is None, path
            (trial,) = api.get(f"/api/v1/studies/{study['id']}/trials").json()
            assert trial["state"] == "queued" and trial["attempts"] == 0, (path, trial)
            recorded = api.get(f"/api/v1/studies/{study['id']}").json()
            assert recorded["proposal_failures"] == failures, (path, recorded)
            assert "connection dropped" in recorded["proposal_error"], recorded
        failing["on"] = False
        time.sleep(0.25)
        job = lease(api, "w2")
        assert job is not None and job["trial_id"] == trial["id"] and job["attempt"] == 1
        assert job["shared"] is None  # the study has no version yet
    finally:
        sa.event.remove(engine, "before_cursor_execute", drop_shared_reads)


@pytest.fixture
def short_lease_api(settings: Settings) -> Any:
    quick = settings.model_copy(update={"lease_seconds": 0.3, "sweep_seconds": 60.0})
    with TestClient(create_app(quick), base_url=LOCAL, headers=SDK_HEADERS) as client:
        yield client


def test_expired_lease_is_requeued_and_the_old_holder_is_refused(
    short_lease_api: TestClient,
) -> None:
    api = short_lease_api
    managed(api, max_trials=1)
    job = lease(api, "slow")
    assert job is not None
    time.sleep(0.5)
    again = lease(api, "fast")
    assert again is not None and again["trial_id"] == job["trial_id"] and again["attempt"] == 2
    trial_url = f"/api/v1/trials/{job['trial_id']}"
    assert api.post(f"{trial_url}/heartbeat", json={"worker_id": "slow"}).status_code == 409
    late = api.post(f"{trial_url}/tell", json={"value": 9.0, "worker_id": "slow"})
    assert late.status_code == 409
    ok = api.post(f"{trial_url}/tell", json={"value": 2.0, "worker_id": "fast"})
    assert ok.status_code == 200 and ok.json()["attempts"] == 2


def test_lease_fails_the_trial_after_max_attempts(short_lease_api: TestClient) -> None:
    api = short_lease_api
    study = managed(api, max_trials=1, max_attempts=2)
    assert lease(api, "a") is not None
    time.sleep(0.5)
    assert lease(api, "b") is not None
    time.sleep(0.5)
    assert lease(api, "c") is None
    (trial,) = api.get(f"/api/v1/studies/{study['id']}/trials").json()
    assert trial["state"] == "failed" and "2 attempts" in trial["message"]
    assert api.get(f"/api/v1/studies/{study['id']}").json()["state"] == "complete"


def test_stopped_study_is_not_leased(api: TestClient) -> None:
    study = managed(api)
    api.post(f"/api/v1/studies/{study['id']}/stop")
    assert lease(api, "w1") is None


def test_studies_without_a_task_are_never_leased(api: TestClient) -> None:
    """Regression: a task-less study stored JSON 'null', which counted as a task."""
    body = copy.deepcopy(BOX_STUDY) | {"max_trials": 5}
    api.post("/api/v1/studies", json=body)
    assert lease(api, "w1") is None


def test_workers_are_listed_newest_first_a_bounded_page_at_a_time(api: TestClient) -> None:
    study = managed(api, max_trials=3)
    for worker in ("w1", "w2", "w3"):
        assert lease(api, worker) is not None

    def page(path: str, **query: int) -> list[str]:
        response = api.get(path, params=query)
        assert response.status_code == 200, response.text
        return [worker["worker_id"] for worker in response.json()]

    assert page("/api/v1/workers") == ["w3", "w2", "w1"]
    assert page("/api/v1/workers", limit=2) == ["w3", "w2"]
    assert page("/api/v1/workers", offset=2, limit=2) == ["w1"]
    assert page(f"/api/v1/studies/{study['id']}/workers", offset=1, limit=1) == ["w2"]
    for bad in ({"limit": 0}, {"limit": MAX_WORKER_PAGE + 1}, {"offset": -1}):
        response = api.get("/api/v1/workers", params=bad)
        assert response.status_code == 422 and next(iter(bad)) in response.text, response.text


def test_a_lease_settles_spent_studies_with_one_expression_built_once(api: TestClient) -> None:
    """Every lease settles the spent studies' paused trials first: the condition of a
    spent study is one expression for them all, not one built per lease (1.5 ms each)."""
    managed(api, max_trials=2)
    spent = promotion._spent()
    assert lease(api, "a") is not None and lease(api, "b") is not None
    assert lease(api, "c") is None
    assert promotion._spent() is spent
