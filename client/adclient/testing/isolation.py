"""One study's heavy ask beside everything else (issue 13): a qei study whose next ask
is heavy, a managed study whose leases propose at once, and asks queued behind the heavy
one. A test checks that the others are answered while the heavy ask computes;
bench/ask_isolation.py measures how fast."""

from __future__ import annotations

import threading
from typing import Any

import httpx
import numpy as np


def box(dim: int) -> dict:
    return {
        "type": "box",
        "params": [{"name": f"x{i}", "low": 0.0, "high": 1.0} for i in range(dim)],
    }


def heavy_study(
    http: httpx.Client,
    name: str,
    dim: int,
    told: int,
    room: int,
    options: dict[str, Any] | None = None,
) -> int:
    """A qei study (with these proposer ``options``) holding ``told`` observations with
    room for ``room`` more trials."""
    study = http.post(
        "/api/v1/studies",
        json={
            "name": name,
            "space": box(dim),
            "proposer": {"name": "qei", "n_initial": told, "options": options or {}},
            "max_trials": told + room,
        },
    ).json()
    trials = http.post(f"/api/v1/studies/{study['id']}/ask", json={"count": told}).json()["trials"]
    for trial in trials:
        x = np.array(trial["vector"])
        value = float(-np.sum((x - 0.3) ** 2) + 0.2 * np.sin(5 * x.sum()))
        http.post(f"/api/v1/trials/{trial['id']}/tell", json={"value": value}).raise_for_status()
    return int(study["id"])


def managed_study(http: httpx.Client) -> int:
    """A managed study with the ``random`` proposer: its leases propose instantly."""
    study = http.post(
        "/api/v1/studies",
        json={
            "name": "B",
            "space": box(2),
            "proposer": {"name": "random"},
            "task": {"name": "noop", "external": True},
            "max_trials": 1_000_000,
        },
    )
    study.raise_for_status()
    return int(study.json()["id"])


def waiting_asks(
    http: httpx.Client, study_id: int, count: int
) -> tuple[list[threading.Thread], list]:
    """``count`` asks of one point queued behind the study's heavy ask, and their status
    codes: the heavy ask fills the study, so each is refused (409) when its turn comes.
    Before issue 13 each waited for that turn holding a request thread. The threads
    share ``http`` (each ask on a connection of its pool: it must allow ``count`` more
    at once; a client apiece loads the CA bundle, 50 ms of CPU each)."""
    statuses: list[int] = []

    def ask() -> None:
        response = http.post(f"/api/v1/studies/{study_id}/ask", json={"count": 1})
        statuses.append(response.status_code)

    threads = [threading.Thread(target=ask) for _ in range(count)]
    for thread in threads:
        thread.start()
    return threads, statuses
