"""A trial whose controller started from another trial's (``task.transfer``, issue 27)
is marked in the dashboard's trials table with that trial, and one that made a version
of its study's shared controller (issue 38) with the versions, in a real headless
Chromium against a real ``adserver``; a trial trained from scratch carries no mark."""

from __future__ import annotations

import httpx
import pytest

from adclient.testing.servers import SDK_HEADERS, ServerProcess
from tests.service.chromium import Chromium

pytestmark = [
    pytest.mark.browser,
    pytest.mark.e2e,
    pytest.mark.xdist_group("browser"),
    # The source on PostgreSQL: test_dashboard_reads (the trials table's marks), on both.
    pytest.mark.parametrize("database", ["sqlite"]),
]


def test_a_warm_started_trial_names_its_source(
    live_server: ServerProcess, browser: Chromium
) -> None:
    with httpx.Client(base_url=live_server.url, headers=SDK_HEADERS, timeout=30) as http:
        space = {"type": "box", "params": [{"name": "x", "low": 0, "high": 1}]}
        task = {"name": "mine", "external": True, "transfer": "nearest"}
        body = {"name": "warm", "space": space, "task": task, "max_trials": 2}
        study = http.post("/api/v1/studies", json=body).json()["id"]
        first = http.post("/api/v1/jobs/lease", json={"worker_id": "w"}).json()
        second = http.post("/api/v1/jobs/lease", json={"worker_id": "w"}).json()
        for job, source in ((first, None), (second, first["trial_id"])):
            put = http.put(  # a source is a trial with a worker's checkpoint
                f"/api/v1/trials/{job['trial_id']}/artifacts/checkpoint.zip",
                params={"worker_id": "w"},
                content=b"PK",
            )
            assert put.status_code == 201, put.text
            told = {"value": 1.0, "worker_id": "w", "transfer_from": source}
            response = http.post(f"/api/v1/trials/{job['trial_id']}/tell", json=told)
            assert response.status_code == 200, response.text
    browser.navigate(f"{live_server.url}/#/studies/{study}")
    marks = browser.wait_for(
        "(() => { const rows = [...document.querySelectorAll('[data-trial-id]')];"
        " return rows.length === 2 ? Object.fromEntries(rows.map(row => [row.dataset.trialId,"
        " row.querySelector('[data-transfer-from]')?.textContent ?? null])) : null; })()"
    )
    assert marks == {
        str(first["trial_id"]): None,
        str(second["trial_id"]): f"from trial {first['trial_id']}",
    }


def test_a_trial_that_made_a_shared_version_says_which(
    live_server: ServerProcess, browser: Chromium
) -> None:
    with httpx.Client(base_url=live_server.url, headers=SDK_HEADERS, timeout=30) as http:
        space = {"type": "box", "params": [{"name": "x", "low": 0, "high": 1}]}
        task = {"name": "mine", "external": True, "transfer": "shared"}
        body = {"name": "shared", "space": space, "task": task, "max_trials": 3}
        study = http.post("/api/v1/studies", json=body).json()["id"]
        jobs = [http.post("/api/v1/jobs/lease", json={"worker_id": "w"}).json() for _ in range(3)]
        for job, base in ((jobs[0], None), (jobs[1], 1)):
            put = http.put(
                f"/api/v1/trials/{job['trial_id']}/artifacts/shared-controller.npz",
                params={"worker_id": "w"},
                content=b"PK",
            )
            assert put.status_code == 201, put.text
            made = http.post(
                f"/api/v1/trials/{job['trial_id']}/shared-controller",
                json={"worker_id": "w", "base_version": base},
            )
            assert made.status_code == 200, made.text
        for job in jobs:
            told = {"value": 1.0, "worker_id": "w"}
            response = http.post(f"/api/v1/trials/{job['trial_id']}/tell", json=told)
            assert response.status_code == 200, response.text
    browser.navigate(f"{live_server.url}/#/studies/{study}")
    marks = browser.wait_for(
        "(() => { const rows = [...document.querySelectorAll('[data-trial-id]')];"
        " return rows.length === 3 ? Object.fromEntries(rows.map(row => [row.dataset.trialId,"
        " row.querySelector('[data-shared-version]')?.textContent ?? null])) : null; })()"
    )
    assert marks == {
        str(jobs[0]["trial_id"]): "shared initial → v1",
        str(jobs[1]["trial_id"]): "shared v1 → v2",
        str(jobs[2]["trial_id"]): None,
    }
