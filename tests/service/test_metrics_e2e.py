"""``GET /metrics`` of real ``adserver`` processes: it moves with the work (asks, tells,
leases by an HTTP caller and by a real ``adworker``), its database gauges agree with the
database, two servers on one PostgreSQL report the same gauges, and readers only when
auth is on."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import httpx
import pytest

from adclient.schemas import TrialState
from adclient.testing.metrics import Samples, in_database, scrape, trials_reported
from adclient.testing.servers import ServerProcess, make_token
from adclient.testing.workers import WorkerProcess

pytestmark = pytest.mark.e2e

BOX = {"type": "box", "params": [{"name": "x", "low": 0.0, "high": 1.0}]}
ASK_TELL = {"name": "asked", "space": BOX, "proposer": {"name": "random", "seed": 1}}
MANAGED = {
    "name": "managed",
    "space": BOX,
    "proposer": {"name": "random", "seed": 2},
    "task": {"name": "metered", "external": True},
    "max_trials": 6,
}
SCORER = "def score(job):\n    return job.params['x']\n"


def database_gauges(samples: Samples) -> Samples:
    names = ("activedesign_trials", "activedesign_leases_active", "activedesign_queue_depth")
    return {key: value for key, value in samples.items() if key[0] in names}


def trials_by_state(samples: Samples, study: int) -> dict[str, float]:
    return {
        dict(labels)["state"]: value
        for (name, labels), value in samples.items()
        if name == "activedesign_trials" and dict(labels)["study"] == str(study)
    }


def assert_agrees_with_database(samples: Samples, database_url: str) -> None:
    counts, leases = in_database(database_url)
    assert trials_reported(samples) == counts
    assert samples[("activedesign_leases_active", ())] == leases


def count(samples: Samples, name: str, **labels: str) -> float:
    return samples.get((name, tuple(sorted(labels.items()))), 0.0)


def test_metrics_move_with_the_work_and_agree_with_the_database(
    server_factory: Callable[..., ServerProcess], tmp_path: Path
) -> None:
    server = server_factory()
    before = scrape(server.url)
    assert count(before, "activedesign_tells_total") == 0
    assert count(before, "activedesign_leases_active") == 0
    with httpx.Client(base_url=server.url, timeout=60, verify=False) as http:
        asked = http.post("/api/v1/studies", json=ASK_TELL).json()["id"]
        managed = http.post("/api/v1/studies", json=MANAGED).json()["id"]
        trials = http.post(f"/api/v1/studies/{asked}/ask", json={"count": 3}).json()["trials"]
        for trial in trials[:2]:
            assert http.post(f"/api/v1/trials/{trial['id']}/tell", json={"value": 1.0}).is_success
        jobs = [
            http.post("/api/v1/jobs/lease", json={"worker_id": f"w{i}"}).json() for i in range(2)
        ]
        released = http.post(
            f"/api/v1/trials/{jobs[1]['trial_id']}/release", json={"worker_id": "w1"}
        )
        assert released.is_success, released.text
    during = scrape(server.url)
    assert count(during, "activedesign_tells_total") == 2
    assert count(during, "activedesign_ask_seconds_count") == 1
    states = trials_by_state(during, asked)
    assert set(states) == set(TrialState)  # every state, zeros too: a series never vanishes
    assert {state: n for state, n in states.items() if n} == {"running": 1, "complete": 2}
    assert trials_by_state(during, managed)["queued"] == 1
    assert count(during, "activedesign_leases_active") == 1  # asked trials hold no lease
    # Waiting for a worker: the released trial, and the four the study may still propose.
    assert count(during, "activedesign_queue_depth", task="metered") == 1 + 4
    assert count(during, "activedesign_queue_depth", task="stand-up") == 0
    assert_agrees_with_database(during, server.database_url)
    tell_route = {"method": "POST", "route": "/api/v1/trials/{trial_id}/tell", "status": "200"}
    tells = "activedesign_http_request_duration_seconds_count"
    assert count(during, tells, **tell_route) == 2
    routes = {dict(labels)["route"] for name, labels in during if name == tells}
    assert routes == {  # templates, never a raw path with an id in it
        "/healthz",
        "/metrics",
        "/api/v1/studies",
        "/api/v1/studies/{study_id}/ask",
        "/api/v1/trials/{trial_id}/tell",
        "/api/v1/jobs/lease",
        "/api/v1/trials/{trial_id}/release",
    }

    # A real worker finishes the managed study, its held trial left to expire elsewhere.
    (tmp_path / "app").mkdir()
    (tmp_path / "app" / "scorer.py").write_text(SCORER)
    worker = WorkerProcess(
        server,
        tmp_path,
        "real",
        *("--app-dir", str(tmp_path / "app"), "--function", "scorer:score"),
        *("--task", "metered", "--max-jobs", "5"),
    )
    try:
        assert worker.wait() == 0, worker.log()
    finally:
        worker.stop()
    after = scrape(server.url)
    assert count(after, "activedesign_tells_total") == 2 + 5
    assert trials_by_state(after, managed)["complete"] == 5
    assert count(after, "activedesign_queue_depth", task="metered") == 0
    assert count(after, "activedesign_leases_active") == 1  # w0's, still held
    assert_agrees_with_database(after, server.database_url)
    assert count(after, tells, **tell_route) == 2 + 5


@pytest.mark.postgres
def test_two_servers_on_one_postgres_report_the_same_database_gauges(
    two_servers: tuple[ServerProcess, ServerProcess],
) -> None:
    """Database gauges are the database's on every replica; counters are each process's
    own, and sum to the work done through both."""
    first, second = two_servers
    with (
        httpx.Client(base_url=first.url, timeout=60, verify=False) as one,
        httpx.Client(base_url=second.url, timeout=60, verify=False) as other,
    ):
        study = one.post("/api/v1/studies", json=MANAGED | {"max_trials": 8}).json()["id"]
        jobs = [
            (one if i % 2 else other).post("/api/v1/jobs/lease", json={"worker_id": f"w{i}"})
            for i in range(5)
        ]
        for i, job in enumerate(jobs[:3]):
            told = (other if i % 2 else one).post(
                f"/api/v1/trials/{job.json()['trial_id']}/tell",
                json={"value": float(i), "worker_id": f"w{i}"},
            )
            assert told.is_success, told.text
    scrapes = [scrape(server.url) for server in two_servers]
    assert database_gauges(scrapes[0]) == database_gauges(scrapes[1])
    assert trials_by_state(scrapes[0], study)["complete"] == 3
    assert count(scrapes[0], "activedesign_leases_active") == 2
    assert count(scrapes[0], "activedesign_queue_depth", task="metered") == 8 - 5
    assert_agrees_with_database(scrapes[0], first.database_url)
    tells = [count(samples, "activedesign_tells_total") for samples in scrapes]
    assert tells == [2, 1]


def test_metrics_need_a_reader_token_when_auth_is_on(
    server_factory: Callable[..., ServerProcess],
) -> None:
    server = server_factory(AD_AUTH="true")
    reader = make_token(server, "reader")
    missing = httpx.get(f"{server.url}/metrics", timeout=30, verify=False)
    assert missing.status_code == 401 and missing.headers["WWW-Authenticate"] == "Bearer"
    forged = httpx.get(
        f"{server.url}/metrics",
        headers={"Authorization": "Bearer adt_forged"},
        timeout=30,
        verify=False,
    )
    assert forged.status_code == 401
    samples = scrape(server.url, reader)
    assert count(samples, "activedesign_leases_active") == 0
    refused = "activedesign_http_request_duration_seconds_count"
    assert count(samples, refused, method="GET", route="unrouted", status="401") == 2
