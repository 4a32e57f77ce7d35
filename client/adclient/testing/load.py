"""The simulated-worker load driver: threads, each with its own HTTP connection, do what
``adworker`` does minus the physics (lease a job, send a heartbeat, compute a cheap
score, tell it) against a real ``adserver``, spread over a few client processes so the
clients' own interpreter lock does not set the pace. :func:`run_load` reports the
latencies it saw and what the server stored: trials lost (acknowledged tells not stored
as told, or trials never told), duplicated (a trial leased twice or a trial number used
twice) and stuck (not finished at the end). bench/load.py runs it at scale; a test runs
it small on each database."""

from __future__ import annotations

import math
import multiprocessing
import threading
import time
from collections import Counter
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
import numpy as np

from adclient import Client
from adclient.testing.noop import score_params as score
from adclient.testing.servers import ServerProcess

ENDPOINTS = ("lease", "heartbeat", "tell")
SPACE = {
    "type": "box",
    "params": [{"name": "x", "low": -2.0, "high": 2.0}, {"name": "y", "low": -2.0, "high": 2.0}],
}


@dataclass
class ClientResult:
    latencies: dict[str, list[float]] = field(default_factory=lambda: {e: [] for e in ENDPOINTS})
    leased: list[int] = field(default_factory=list)
    told: dict[int, float] = field(default_factory=dict)
    errors: Counter[str] = field(default_factory=Counter)

    def merge(self, other: ClientResult) -> None:
        for endpoint in ENDPOINTS:
            self.latencies[endpoint].extend(other.latencies[endpoint])
        self.leased.extend(other.leased)
        self.told.update(other.told)
        self.errors.update(other.errors)


def run_clients(url: str, study_id: int, worker_names: list[str], deadline: float) -> ClientResult:
    """One client process: a thread per simulated worker; returns what they saw."""
    result = ClientResult()
    guard = threading.Lock()

    def worker(name: str) -> None:
        mine = ClientResult()
        with httpx.Client(base_url=url, timeout=60, verify=False) as http:
            while time.time() < deadline:
                started = time.perf_counter()
                leased = http.post("/api/v1/jobs/lease", json={"worker_id": name})
                mine.latencies["lease"].append(time.perf_counter() - started)
                if leased.status_code == 204:
                    state = http.get(f"/api/v1/studies/{study_id}").json()["state"]
                    if state != "running":
                        break
                    time.sleep(0.2)  # others still hold the last trials: one may come back
                    continue
                if leased.status_code != 200:
                    mine.errors[f"lease {leased.status_code}"] += 1
                    time.sleep(0.1)
                    continue
                job = leased.json()
                trial_id = job["trial_id"]
                mine.leased.append(trial_id)
                started = time.perf_counter()
                beat = http.post(f"/api/v1/trials/{trial_id}/heartbeat", json={"worker_id": name})
                mine.latencies["heartbeat"].append(time.perf_counter() - started)
                if beat.status_code != 200:
                    mine.errors[f"heartbeat {beat.status_code}"] += 1
                value = score(job["params"])
                started = time.perf_counter()
                told = http.post(
                    f"/api/v1/trials/{trial_id}/tell", json={"value": value, "worker_id": name}
                )
                mine.latencies["tell"].append(time.perf_counter() - started)
                if told.status_code == 200:
                    mine.told[trial_id] = value
                else:
                    mine.errors[f"tell {told.status_code}"] += 1
        with guard:
            result.merge(mine)

    threads = [threading.Thread(target=worker, args=(name,)) for name in worker_names]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    return result


def create_study(url: str, trials: int) -> int:
    """The load study: a managed study of the no-physics task, ``trials`` trials."""
    with httpx.Client(base_url=url, timeout=60, verify=False) as http:
        created = http.post(
            "/api/v1/studies",
            json={
                "name": "load",
                "space": SPACE,
                "proposer": {"name": "random", "seed": 1},
                "task": {"name": "noop", "external": True},
                "max_trials": trials,
            },
        )
        created.raise_for_status()
        return int(created.json()["id"])


def percentile_ms(values: list[float], q: float) -> float:
    return round(float(np.percentile(values, q)) * 1000, 1) if values else math.nan


def run_load(
    database_url: str, workdir: Path, *, workers: int, trials: int, processes: int, limit_s: float
) -> dict[str, Any]:
    """``workers`` simulated workers in ``processes`` client processes run a managed study
    of ``trials`` trials to its end (or for ``limit_s``) against a fresh ``adserver`` on
    ``database_url``: the throughput, latencies per endpoint and what was lost,
    duplicated or stuck."""
    server = ServerProcess(
        database_url=database_url, workdir=workdir, env={"AD_LEASE_SECONDS": "60"}
    ).start()
    try:
        study_id = create_study(server.url, trials)
        names = [f"sim-{i:02d}" for i in range(workers)]
        groups = [names[i::processes] for i in range(processes)]
        deadline = time.time() + limit_s
        started = time.perf_counter()
        context = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(max_workers=processes, mp_context=context) as pool:
            parts = [
                pool.submit(run_clients, server.url, study_id, group, deadline) for group in groups
            ]
            seen = ClientResult()
            for part in parts:
                seen.merge(part.result())
        elapsed = time.perf_counter() - started
        with Client(server.url, timeout=120) as sdk:  # pages through every trial
            stored = [trial.model_dump(mode="json") for trial in sdk.trials(study_id)]
            study = sdk.study_info(study_id).model_dump(mode="json")
    finally:
        server.stop()

    by_id = {trial["id"]: trial for trial in stored}
    lease_counts = Counter(seen.leased)
    number_counts = Counter(trial["number"] for trial in stored)
    lost_tells = sum(
        1
        for trial_id, value in seen.told.items()
        if by_id.get(trial_id, {}).get("state") != "complete" or by_id[trial_id]["value"] != value
    )
    never_told = sum(1 for trial in stored if trial["id"] not in seen.told)
    duplicated = sum(n - 1 for n in lease_counts.values() if n > 1) + sum(
        n - 1 for n in number_counts.values() if n > 1
    )
    stuck = sum(1 for trial in stored if trial["state"] not in ("complete", "failed"))
    complete = sum(1 for trial in stored if trial["state"] == "complete")
    return {
        "trials": trials,
        "workers": workers,
        "client_processes": processes,
        "seconds": round(elapsed, 1),
        "trials_per_s": round(complete / elapsed, 1),
        "latency_ms": {
            endpoint: {
                "p50": percentile_ms(seen.latencies[endpoint], 50),
                "p99": percentile_ms(seen.latencies[endpoint], 99),
                "n": len(seen.latencies[endpoint]),
            }
            for endpoint in ENDPOINTS
        },
        "errors": dict(seen.errors),
        "stored": len(stored),
        "complete": complete,
        "study_state": study["state"],
        "lost": lost_tells + never_told,
        "duplicated": duplicated,
        "stuck": stuck,
    }
