"""Many concurrent workers and ask/tell clients against a real server on a SQLite file."""

from __future__ import annotations

import threading
from collections import Counter
from typing import Any

import httpx
import pytest

from adclient.testing.servers import ServerProcess

pytestmark = pytest.mark.e2e

BOX = {"type": "box", "params": [{"name": "x", "low": 0.0, "high": 1.0}]}


def test_concurrent_leases_and_tells_lose_and_duplicate_nothing(live_server: ServerProcess) -> None:
    n_workers, n_trials = 8, 120
    with httpx.Client(base_url=live_server.url, timeout=30, verify=False) as http:
        study = http.post(
            "/api/v1/studies",
            json={
                "name": "managed",
                "space": BOX,
                "proposer": {"name": "random"},
                "task": {"name": "noop", "external": True},
                "max_trials": n_trials,
            },
        ).json()
    leased: list[int] = []
    told: dict[int, float] = {}
    errors: list[str] = []
    guard = threading.Lock()

    def work(worker: str) -> None:
        with httpx.Client(base_url=live_server.url, timeout=30, verify=False) as http:
            while True:
                response = http.post("/api/v1/jobs/lease", json={"worker_id": worker})
                if response.status_code == 204:
                    return
                if response.status_code != 200:
                    errors.append(f"lease {response.status_code}: {response.text}")
                    return
                job = response.json()
                value = job["trial_id"] * 0.5
                tell = http.post(
                    f"/api/v1/trials/{job['trial_id']}/tell",
                    json={"value": value, "worker_id": worker},
                )
                with guard:
                    leased.append(job["trial_id"])
                    if tell.status_code == 200:
                        told[job["trial_id"]] = value
                    else:
                        errors.append(f"tell {tell.status_code}: {tell.text}")

    threads = [threading.Thread(target=work, args=(f"w{i}",)) for i in range(n_workers)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()

    assert errors == []
    assert len(leased) == n_trials and max(Counter(leased).values()) == 1
    with httpx.Client(base_url=live_server.url, timeout=30, verify=False) as http:
        trials = http.get(f"/api/v1/studies/{study['id']}/trials").json()
        info = http.get(f"/api/v1/studies/{study['id']}").json()
    assert len(trials) == n_trials
    assert sorted(t["number"] for t in trials) == list(range(n_trials))
    assert {t["id"]: t["value"] for t in trials} == told
    assert info["n_complete"] == n_trials and info["state"] == "complete"


def test_concurrent_asks_on_one_study_get_distinct_trials(live_server: ServerProcess) -> None:
    with httpx.Client(base_url=live_server.url, timeout=30, verify=False) as http:
        study = http.post(
            "/api/v1/studies", json={"name": "s", "space": BOX, "proposer": {"name": "sobol"}}
        ).json()
    results: list[dict[str, Any]] = []
    guard = threading.Lock()

    def client() -> None:
        with httpx.Client(base_url=live_server.url, timeout=30, verify=False) as http:
            for _ in range(10):
                trials = http.post(f"/api/v1/studies/{study['id']}/ask", json={"count": 2}).json()[
                    "trials"
                ]
                for trial in trials:
                    told = http.post(f"/api/v1/trials/{trial['id']}/tell", json={"value": 1.0})
                    assert told.status_code == 200
                with guard:
                    results.extend(trials)

    threads = [threading.Thread(target=client) for _ in range(8)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert len(results) == 160
    assert len({t["id"] for t in results}) == 160
    assert len({t["number"] for t in results}) == 160
    assert len({tuple(t["vector"]) for t in results}) == 160  # Sobol points never repeat
