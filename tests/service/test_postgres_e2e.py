"""Two ``adserver`` processes on one PostgreSQL database serve one study: workers lease
from one, heartbeat and tell through the other, and nothing is leased twice or lost."""

from __future__ import annotations

import threading
from collections import Counter
from typing import Any

import httpx
import pytest
import sqlalchemy as sa

from adclient.testing.servers import ServerProcess

pytestmark = [pytest.mark.e2e, pytest.mark.postgres]

BOX = {
    "type": "box",
    "params": [{"name": "x", "low": 0.0, "high": 1.0}, {"name": "y", "low": 0.0, "high": 1.0}],
}


def test_workers_across_two_servers_lose_and_duplicate_nothing(
    two_servers: tuple[ServerProcess, ServerProcess],
) -> None:
    """First some workers lease trials and vanish; their leases are made to run out (in
    the database, instead of waiting), so the rest lease both re-queued and new trials."""
    n_workers, n_trials, n_abandoned = 12, 240, 40
    urls = [server.url for server in two_servers]
    with httpx.Client(base_url=urls[0], timeout=60, verify=False) as http:
        created = http.post(
            "/api/v1/studies",
            json={
                "name": "shared",
                "space": BOX,
                "proposer": {"name": "random", "seed": 5},
                "task": {"name": "noop", "external": True},
                "max_trials": n_trials,
            },
        )
        assert created.status_code == 201, created.text
        study = created.json()
        abandoned = {
            http.post("/api/v1/jobs/lease", json={"worker_id": f"gone{i}"}).json()["trial_id"]
            for i in range(n_abandoned)
        }
    assert len(abandoned) == n_abandoned
    engine = sa.create_engine(two_servers[0].database_url)
    with engine.begin() as connection:
        expired = connection.execute(
            sa.text(
                "UPDATE trials SET lease_expires_at = lease_expires_at - interval '1 day' "
                "WHERE state = 'running'"
            )
        ).rowcount
    engine.dispose()
    assert expired == n_abandoned
    leased: list[int] = []
    told: dict[int, float] = {}
    errors: list[str] = []
    guard = threading.Lock()

    def work(index: int) -> None:
        worker = f"w{index}"
        near, far = (
            httpx.Client(base_url=urls[(index + k) % 2], timeout=60, verify=False) for k in (0, 1)
        )
        with near, far:
            while True:
                response = near.post("/api/v1/jobs/lease", json={"worker_id": worker})
                if response.status_code == 204:
                    return
                if response.status_code != 200:
                    with guard:
                        errors.append(f"lease {response.status_code}: {response.text}")
                    return
                trial_id = response.json()["trial_id"]
                beat = far.post(f"/api/v1/trials/{trial_id}/heartbeat", json={"worker_id": worker})
                value = trial_id * 0.25
                tell = far.post(
                    f"/api/v1/trials/{trial_id}/tell", json={"value": value, "worker_id": worker}
                )
                with guard:
                    leased.append(trial_id)
                    if beat.status_code != 200:
                        errors.append(f"heartbeat {beat.status_code}: {beat.text}")
                    if tell.status_code == 200:
                        told[trial_id] = value
                    else:
                        errors.append(f"tell {tell.status_code}: {tell.text}")

    threads = [threading.Thread(target=work, args=(i,)) for i in range(n_workers)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()

    assert errors == []
    assert len(leased) == n_trials
    assert Counter(leased).most_common(1)[0][1] == 1
    assert abandoned <= set(leased)
    for url in urls:  # both servers see the same, complete study
        with httpx.Client(base_url=url, timeout=60, verify=False) as http:
            trials = http.get(f"/api/v1/studies/{study['id']}/trials").json()
            info = http.get(f"/api/v1/studies/{study['id']}").json()
        assert sorted(t["number"] for t in trials) == list(range(n_trials))
        assert {t["id"]: t["value"] for t in trials} == told
        attempts = {t["id"]: t["attempts"] for t in trials}
        assert {i for i, n in attempts.items() if n == 2} == abandoned
        assert {i for i, n in attempts.items() if n != 2} == set(told) - abandoned
        assert info["n_complete"] == n_trials and info["state"] == "complete"


def test_model_based_asks_through_two_servers_take_turns(
    two_servers: tuple[ServerProcess, ServerProcess],
) -> None:
    """TPE is seeded from the study's seed and ``n_issued`` and sees the same history:
    two asks that did not take turns (an advisory lock across servers) would get the same
    point (without the lock this test fails)."""
    urls = [server.url for server in two_servers]
    with httpx.Client(base_url=urls[0], timeout=60, verify=False) as http:
        created = http.post(
            "/api/v1/studies",
            json={"name": "turns", "space": BOX, "proposer": {"name": "tpe", "n_initial": 1}},
        )
        assert created.status_code == 201, created.text
        study = created.json()
    results: list[dict[str, Any]] = []
    errors: list[str] = []
    guard = threading.Lock()

    def client(index: int) -> None:
        with httpx.Client(base_url=urls[index % 2], timeout=60, verify=False) as http:
            for _ in range(12):
                asked = http.post(f"/api/v1/studies/{study['id']}/ask", json={"count": 1})
                with guard:
                    if asked.status_code == 200:
                        results.extend(asked.json()["trials"])
                    else:
                        errors.append(f"ask {asked.status_code}: {asked.text}")

    threads = [threading.Thread(target=client, args=(i,)) for i in range(8)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert errors == []
    assert len(results) == 96
    assert sorted(t["number"] for t in results) == list(range(96))
    assert len({tuple(t["vector"]) for t in results}) == 96
