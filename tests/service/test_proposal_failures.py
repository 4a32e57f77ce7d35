"""Issue 36: one study's failing proposals stay its own. A study whose proposals raise is
recorded (error, failures in a row, retry time), skipped by the lease scheduler with
a backoff that doubles up to a cap and resets on success, and shown in its answer and
/metrics; the lease that met the failure goes on to the next study, an owner's ask
answers 409 naming it, and nothing of the failed proposal is stored. On SQLite and
PostgreSQL (``database_url``)."""

from __future__ import annotations

from datetime import datetime, timedelta
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from adclient.testing.servers import SDK_HEADERS
from adservice.app import create_app
from adservice.models import utcnow
from adservice.settings import Settings
from tests.failing_proposals import (
    ERROR,
    design_study,
    read_representation,
    store_representation,
    unfit_representation,
    update_study,
)
from tests.service.conftest import LOCAL

BACKOFF = 60.0
CAP = 150.0
TASK = {"name": "score", "external": True}
RANDOM = {"name": "random", "seed": 1}
GOOD = {
    "name": "good",
    "space": {"type": "box", "params": [{"name": "x", "low": 0.0, "high": 1.0}]},
    "proposer": {"name": "random", "seed": 1},
    "task": TASK,
    "max_trials": 10,
}


@pytest.fixture
def settings(tmp_path: Path, database_url: str) -> Settings:
    return Settings(
        database_url=database_url,
        artifact_dir=tmp_path / "artifacts",
        proposal_backoff_seconds=BACKOFF,
        proposal_backoff_max_seconds=CAP,
    )


def created(api: TestClient, body: dict[str, Any]) -> int:
    response = api.post("/api/v1/studies", json=body)
    assert response.status_code == 201, response.text
    return int(response.json()["id"])


def study(api: TestClient, study_id: int) -> dict[str, Any]:
    return dict(api.get(f"/api/v1/studies/{study_id}").json())


def lease(api: TestClient, worker_id: str) -> dict[str, Any]:
    response = api.post("/api/v1/jobs/lease", json={"worker_id": worker_id})
    assert response.status_code == 200, response.text
    return dict(response.json())


def retry_at(answer: dict[str, Any]) -> datetime:
    return datetime.fromisoformat(answer["proposal_retry_at"])


def backoff_over(database_url: str, study_id: int) -> None:
    """As if the study's backoff had passed (the tests' backoffs are long, so that no
    lease can come after one by chance on a slow machine)."""
    update_study(database_url, study_id, proposal_retry_at=utcnow() - timedelta(seconds=1))


def gauge(api: TestClient, line_start: str) -> float:
    (line,) = [
        line for line in api.get("/metrics").text.splitlines() if line.startswith(line_start)
    ]
    return float(line.split()[-1])


def assert_nothing_stored(api: TestClient, study_id: int) -> None:
    answer = study(api, study_id)
    assert answer["n_trials"] == 0, answer
    assert api.get(f"/api/v1/studies/{study_id}/trials").json() == []


def test_a_failing_study_backs_off_and_every_lease_goes_on(
    api: TestClient, settings: Settings, database_url: str
) -> None:
    failing = created(api, design_study("failing", task=TASK, max_trials=5, proposer=RANDOM))
    representation = unfit_representation(database_url, failing)
    good = created(api, GOOD)

    # The failing study is older, so a lease tries it first: the same lease answers a
    # job of the good study, and the failure is recorded with its first backoff.
    before = utcnow()
    assert lease(api, "w0")["study_id"] == good
    after = utcnow()
    answer = study(api, failing)
    assert answer["proposal_failures"] == 1
    assert answer["proposal_error"].startswith(ERROR), answer
    assert before + timedelta(seconds=BACKOFF) <= retry_at(answer)
    assert retry_at(answer) <= after + timedelta(seconds=BACKOFF)
    assert_nothing_stored(api, failing)
    assert gauge(api, f'activedesign_proposal_failures{{study="{failing}"}}') == 1
    assert gauge(api, f'activedesign_proposal_failures{{study="{good}"}}') == 0
    # Backing off, it waits for no worker: the queue is the good study's room alone.
    assert gauge(api, 'activedesign_queue_depth{task="score"}') == GOOD["max_trials"] - 1

    # Until its retry time leases skip it (not tried: no new failure).
    assert lease(api, "w1")["study_id"] == good
    assert study(api, failing)["proposal_failures"] == 1

    # Once its backoff is over a lease tries it again, and the wait doubles.
    backoff_over(database_url, failing)
    before = utcnow()
    assert lease(api, "w2")["study_id"] == good
    after = utcnow()
    answer = study(api, failing)
    assert answer["proposal_failures"] == 2
    assert before + timedelta(seconds=2 * BACKOFF) <= retry_at(answer)
    assert retry_at(answer) <= after + timedelta(seconds=2 * BACKOFF)
    assert_nothing_stored(api, failing)
    numbers = [trial["number"] for trial in api.get(f"/api/v1/studies/{good}/trials").json()]
    assert numbers == [0, 1, 2]

    # Repaired (a server restarted on the right version reads it anew), its next
    # proposal succeeds and clears the record.
    store_representation(database_url, failing, representation)
    backoff_over(database_url, failing)
    with TestClient(create_app(settings), base_url=LOCAL, headers=SDK_HEADERS) as restarted:
        job = lease(restarted, "w3")
        assert (job["study_id"], job["number"], job["attempt"]) == (failing, 0, 1)
        answer = study(restarted, failing)
        assert answer["proposal_failures"] == 0
        assert answer["proposal_error"] is None and answer["proposal_retry_at"] is None
        assert gauge(restarted, f'activedesign_proposal_failures{{study="{failing}"}}') == 0


def test_an_owner_ask_of_a_failing_study_answers_409_naming_the_failure(
    api: TestClient, database_url: str
) -> None:
    # qei: the proposal runs in the proposal threads (random's in a short write).
    failing = created(api, design_study("failing-ask"))
    unfit_representation(database_url, failing)

    # An owner's ask is tried even while leases skip the study; each failure doubles
    # the wait, up to the cap.
    for failures, delay in [(1, BACKOFF), (2, 2 * BACKOFF), (3, CAP), (4, CAP)]:
        before = utcnow()
        response = api.post(f"/api/v1/studies/{failing}/ask", json={"count": 2})
        after = utcnow()
        assert response.status_code == 409, response.text
        body = response.json()
        assert body["error"] == "proposal_failed"
        assert body["detail"].startswith(f"study {failing}'s proposal failed: {ERROR}"), body
        assert f"({failures} in a row; workers' leases skip the study until " in body["detail"]
        assert "Traceback" not in response.text
        answer = study(api, failing)
        assert answer["proposal_failures"] == failures
        assert answer["proposal_error"].startswith(ERROR)
        assert before + timedelta(seconds=delay) <= retry_at(answer)
        assert retry_at(answer) <= after + timedelta(seconds=delay)
        assert_nothing_stored(api, failing)

    # The request's own errors are not the study's: not recorded.
    assert api.post(f"/api/v1/studies/{failing}/stop").status_code == 200
    response = api.post(f"/api/v1/studies/{failing}/ask", json={"count": 1})
    assert response.status_code == 409 and response.json()["error"] == "conflict", response.text
    assert study(api, failing)["proposal_failures"] == 4


def test_a_queued_trial_whose_study_does_not_load_is_skipped_not_a_500(
    settings: Settings, database_url: str
) -> None:
    """A queued trial is leased before its job is built; a study whose stored settings
    do not load (here its representation, corrupted in the file) made that build raise
    after the lease was written: a 500 to every lease, the trial held
    until its lease ran out and the attempt counted. Now the failure is the study's:
    recorded with its backoff, the trial back in the queue uncounted, and the same
    lease answers the next study's job."""
    with TestClient(create_app(settings), base_url=LOCAL, headers=SDK_HEADERS) as api:
        stale = created(api, design_study("stale", task=TASK, max_trials=5, proposer=RANDOM))
        response = api.post(f"/api/v1/studies/{stale}/ask", json={"count": 1})
        assert response.status_code == 200, response.text
        (asked,) = response.json()["trials"]
        enqueued = api.post(f"/api/v1/studies/{stale}/trials", json={"params": asked["params"]})
        assert enqueued.status_code == 201, enqueued.text
        good = created(api, GOOD)
    representation = read_representation(database_url, stale)
    store_representation(database_url, stale, {**representation, "bounds": "lost"})

    with TestClient(create_app(settings), base_url=LOCAL, headers=SDK_HEADERS) as api:
        assert lease(api, "w0")["study_id"] == good
        answer = study(api, stale)
        assert answer["proposal_failures"] == 1, answer
        assert answer["proposal_error"].startswith("ValidationError"), answer
        trials = api.get(f"/api/v1/studies/{stale}/trials").json()
        queued = [trial for trial in trials if trial["state"] == "queued"]
        assert len(queued) == 1 and queued[0]["attempts"] == 0, trials
        # backing off, its queued trial is not leased again: the good study's next job
        assert lease(api, "w1")["study_id"] == good
        assert study(api, stale)["proposal_failures"] == 1
