"""Many concurrent workers and ask/tell clients against a real server, on each kind of
database."""

from __future__ import annotations

import re
import threading
from collections import Counter
from typing import Any

import httpx
import pytest

from adclient.testing.metrics import scrape, trials_reported
from adclient.testing.servers import ServerProcess
from adclient.testing.workers import run_adclient

pytestmark = pytest.mark.e2e

BOX = {"type": "box", "params": [{"name": "x", "low": 0.0, "high": 1.0}]}

STATES = ("complete", "complete", "failed", "pruned")


def told(trial_id: int) -> tuple[str, float | None]:
    """The outcome a worker tells for a trial: a mix of states, values not in id order."""
    state = STATES[trial_id % len(STATES)]
    return state, None if state == "failed" else float((trial_id * 37) % 101)


def test_concurrent_leases_and_tells_lose_and_duplicate_nothing(live_server: ServerProcess) -> None:
    """Workers lease and tell at once (complete, failed and pruned): nothing is leased
    twice or lost, and what the tells feed stays exact: the study's counts (its trials'
    states: a tell writes no counter of the study), its best (written only by a tell that
    beats it) and its end, ``/metrics`` and ``adclient status``."""
    n_workers, n_trials = 16, 160
    with httpx.Client(base_url=live_server.url, timeout=60, verify=False) as http:
        created = http.post(
            "/api/v1/studies",
            json={
                "name": "counted",
                "direction": "maximize",
                "space": BOX,
                "proposer": {"name": "random", "seed": 3},
                "task": {"name": "noop", "external": True},
                "max_trials": n_trials,
            },
        )
        assert created.status_code == 201, created.text
        study = created.json()
    acknowledged: dict[int, tuple[str, float | None]] = {}
    leased: list[int] = []
    errors: list[str] = []
    guard = threading.Lock()
    start = threading.Barrier(n_workers)

    def work(worker: str) -> None:
        with httpx.Client(base_url=live_server.url, timeout=60, verify=False) as http:
            start.wait()
            while True:
                response = http.post("/api/v1/jobs/lease", json={"worker_id": worker})
                if response.status_code == 204:
                    return
                if response.status_code != 200:
                    with guard:
                        errors.append(f"lease {response.status_code}: {response.text}")
                    return
                trial_id = response.json()["trial_id"]
                state, value = told(trial_id)
                tell = http.post(
                    f"/api/v1/trials/{trial_id}/tell",
                    json={"state": state, "value": value, "worker_id": worker},
                )
                with guard:
                    leased.append(trial_id)
                    if tell.status_code == 200:
                        acknowledged[trial_id] = (state, value)
                    else:
                        errors.append(f"tell {tell.status_code}: {tell.text}")

    threads = [threading.Thread(target=work, args=(f"w{i}",)) for i in range(n_workers)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()

    assert errors == []
    assert len(leased) == n_trials and max(Counter(leased).values()) == 1
    expected = Counter(state for state, _ in acknowledged.values())
    assert min(expected.values()) > 0  # every state was told
    completes = {i: v for i, (s, v) in acknowledged.items() if s == "complete"}
    best_value = max(completes.values())
    with httpx.Client(base_url=live_server.url, timeout=60, verify=False) as http:
        info = http.get(f"/api/v1/studies/{study['id']}").json()
        listed = http.get("/api/v1/studies").json()
        trials = http.get(f"/api/v1/studies/{study['id']}/trials").json()
    assert sorted(t["number"] for t in trials) == list(range(n_trials))
    assert {t["id"]: (t["state"], t["value"]) for t in trials} == acknowledged
    counts = (info["n_complete"], info["n_failed"], info["n_pruned"])
    assert counts == (expected["complete"], expected["failed"], expected["pruned"])
    assert (info["n_trials"], info["n_running"], info["n_queued"]) == (n_trials, 0, 0)
    assert info["state"] == "complete"  # the last tell, whichever it was, finished it
    assert info["best_value"] == best_value
    assert completes[info["best_trial_id"]] == best_value
    (in_list,) = [s for s in listed if s["id"] == study["id"]]
    assert (in_list["n_complete"], in_list["n_failed"], in_list["n_pruned"]) == counts

    reported = trials_reported(scrape(live_server.url))
    assert {state: reported.get((study["id"], state), 0) for state in expected} == dict(expected)

    status = run_adclient(live_server, "status", str(study["id"]))
    assert status.returncode == 0, status.stderr
    shown = {
        name: int(match.group(1))
        for name in ("complete", "failed", "pruned")
        if (match := re.search(rf"^\W*{name}\W+(\d+)", status.stdout, re.MULTILINE))
    }
    assert tuple(shown.values()) == counts and len(shown) == 3


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
