"""ASHA promotion against a real ``adserver`` process, over plain HTTP: a worker's trial
stopped at a rung pauses with its checkpoint artifact, waits, is promoted (queued, its
job carrying the checkpoint) once it is in its rung's top fraction, and ends pruned
when the study's budget is spent; the pause contract's errors, only the lease holder's
token pausing; only a worker's checkpoint of the pausing lease resumed from (issue 36)."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from typing import Any

import httpx
import pytest

from adclient.testing.servers import SDK_HEADERS, ServerProcess, make_token
from tests.client.cli_harness import run
from tests.conftest import DATABASES, module_server

pytestmark = [pytest.mark.e2e, pytest.mark.xdist_group("promotion")]

PROMOTION = {
    "name": "asha",
    "options": {"min_resource": 10, "reduction_factor": 2, "promotion": True},
}


def managed(pruner: dict[str, Any], max_trials: int, task: str = "curve") -> dict[str, Any]:
    """A box study that workers of the external ``task`` lease (a test on the shared
    server names a task of its own, so that it leases only its own study's jobs)."""
    return {
        "name": "promoted",
        "direction": "maximize",
        "space": {"type": "box", "params": [{"name": "x", "low": 0, "high": 1}]},
        "proposer": {"name": "random", "seed": 1},
        "task": {"name": task, "external": True},
        "pruner": pruner,
        "max_trials": max_trials,
    }


@pytest.fixture
def http(shared_server: ServerProcess) -> Iterator[httpx.Client]:
    """The module's server: a test leases only its own task's jobs and looks only at its
    own studies."""
    with httpx.Client(
        base_url=shared_server.url, headers=SDK_HEADERS, timeout=30, verify=False
    ) as client:
        yield client


@pytest.fixture(scope="module", params=DATABASES)
def secured(
    request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[ServerProcess]:
    """One server with auth on per kind of database, shared by the module's tests that
    take it: each makes studies of a task of its own and leases only that task's jobs."""
    with module_server(request, tmp_path_factory, "secured", {"AD_AUTH": "true"}) as server:
        yield server


@pytest.fixture(scope="module")
def token(secured: ServerProcess) -> Callable[..., str]:
    """``token(role, name)``: a token of the secured server, made by ``adserver token
    create`` once per role and name for the tests that ask for it."""
    made: dict[tuple[str, str], str] = {}

    def of(role: str, name: str) -> str:
        if (role, name) not in made:
            made[role, name] = make_token(secured, role, name=name)
        return made[role, name]

    return of


def create(http: httpx.Client, body: dict[str, Any]) -> int:
    created = http.post("/api/v1/studies", json=body)
    assert created.status_code == 201, created.text
    return int(created.json()["id"])


def lease(http: httpx.Client, worker: str, task: str = "curve") -> dict[str, Any] | None:
    leased = http.post("/api/v1/jobs/lease", json={"worker_id": worker, "tasks": [task]})
    assert leased.status_code in (200, 204), leased.text
    return leased.json() if leased.status_code == 200 else None


def report(http: httpx.Client, trial: int, worker: str, step: int, value: float) -> dict[str, Any]:
    answer = http.post(
        f"/api/v1/trials/{trial}/report", json={"step": step, "value": value, "worker_id": worker}
    )
    assert answer.status_code == 200, answer.text
    return dict(answer.json())


def upload_checkpoint(http: httpx.Client, trial: int, worker: str) -> None:
    stored = http.put(
        f"/api/v1/trials/{trial}/artifacts/checkpoint.zip",
        params={"worker_id": worker},
        content=b"learner state",
        headers={"Content-Type": "application/zip"},
    )
    assert stored.status_code in (200, 201), stored.text


def pause(http: httpx.Client, trial: int, worker: str, step: int, **extra: Any) -> httpx.Response:
    return http.post(
        f"/api/v1/trials/{trial}/pause", json={"worker_id": worker, "step": step, **extra}
    )


def paused_at_rung(http: httpx.Client, worker: str, value: float, task: str = "curve") -> int:
    """A new trial of ``task`` leased by ``worker``, reported at rung 10, paused there."""
    job = lease(http, worker, task)
    assert job is not None
    answer = report(http, job["trial_id"], worker, 10, value)
    assert answer == {"should_stop": True, "pause": True}, answer
    upload_checkpoint(http, job["trial_id"], worker)
    paused = pause(http, job["trial_id"], worker, 10)
    assert paused.status_code == 200, paused.text
    return int(job["trial_id"])


def trial(http: httpx.Client, trial_id: int) -> dict[str, Any]:
    return dict(http.get(f"/api/v1/trials/{trial_id}").json())


def test_a_paused_trial_waits_and_is_promoted_when_it_qualifies(
    http: httpx.Client, shared_server: ServerProcess
) -> None:
    task = "promoted"
    study = create(http, managed(PROMOTION, max_trials=4, task=task))
    a = lease(http, "wa", task)
    assert a is not None and a["resume"] is None
    assert report(http, a["trial_id"], "wa", 10, 1.0) == {"should_stop": False, "pause": False}

    b = lease(http, "wb", task)
    assert b is not None
    assert report(http, b["trial_id"], "wb", 10, 0.5) == {"should_stop": True, "pause": True}
    below = pause(http, b["trial_id"], "wb", 5)
    assert below.status_code == 422 and "below study" in below.json()["detail"], below.text
    missing = pause(http, b["trial_id"], "wb", 10)
    assert missing.status_code == 409 and "checkpoint.zip" in missing.json()["detail"]
    upload_checkpoint(http, b["trial_id"], "wb")
    for budget in (0, "40", True):  # a budget is a positive integer: nothing stored
        refused = pause(http, b["trial_id"], "wb", 10, budget=budget)
        assert refused.status_code == 422 and "budget" in refused.text, refused.text
        assert trial(http, b["trial_id"])["state"] == "running"
    paused = pause(http, b["trial_id"], "wb", 10, metrics={"time_total_s": 3.0}, budget=40)
    assert paused.status_code == 200, paused.text
    record = paused.json()
    assert (record["state"], record["value"], record["worker_id"]) == ("paused", 0.5, None)
    assert record["checkpoint"] == {
        "artifact": "checkpoint.zip",
        "step": 10,
        "rung": 10,
        "metrics": {"time_total_s": 3.0},
        "lease": 1,
        "budget": 40,
    }
    again = pause(http, b["trial_id"], "wb", 10, metrics={"time_total_s": 3.0}, budget=40)
    assert again.status_code == 200 and again.json()["state"] == "paused"
    late = http.post(
        f"/api/v1/trials/{b['trial_id']}/report",
        json={"step": 20, "value": 9.0, "worker_id": "wb"},
    )
    assert late.status_code == 409 and late.json()["error"] == "lease_lost", late.text
    info = http.get(f"/api/v1/studies/{study}").json()
    assert (info["n_paused"], info["n_running"], info["n_pruned"]) == (1, 1, 0)
    listed = http.get(f"/api/v1/studies/{study}/trials", params={"state": "paused"}).json()
    assert [t["id"] for t in listed] == [b["trial_id"]]
    status = run(shared_server.url, "status", str(study)).stdout
    rows = [
        [cell.strip() for cell in line.split("│") if cell.strip()] for line in status.splitlines()
    ]
    assert ["paused", "1"] in rows, status

    # Rung 10 holds [1.0, 0.5, 0.2]: 3 // 2 - 1 < 0, so only the best goes on; b waits.
    paused_at_rung(http, "wc", 0.2, task)
    assert trial(http, b["trial_id"])["state"] == "paused"
    # A fourth value: 4 // 2 - 1 = 1, the top two go on: 0.5 is the second best now.
    paused_at_rung(http, "wd", 0.1, task)
    assert trial(http, b["trial_id"])["state"] == "queued"

    resumed = lease(http, "we", task)
    assert resumed is not None and resumed["trial_id"] == b["trial_id"], resumed
    assert resumed["resume"] == record["checkpoint"]
    assert resumed["attempt"] == 1  # the paused attempt did not count against max_attempts
    checkpoint = http.get(f"/api/v1/trials/{b['trial_id']}/artifacts/checkpoint.zip")
    assert checkpoint.content == b"learner state"


def test_paused_trials_end_pruned_with_their_value_once_the_budget_is_spent(
    http: httpx.Client,
) -> None:
    task = "budget-spent"
    study = create(http, managed(PROMOTION, max_trials=2, task=task))
    a = lease(http, "wa", task)
    assert a is not None
    report(http, a["trial_id"], "wa", 10, 1.0)
    b = paused_at_rung(http, "wb", 0.5, task)
    assert lease(http, "wc", task) is None  # no room for a new trial, b waits, a still runs
    assert trial(http, b)["state"] == "paused"
    told = http.post(f"/api/v1/trials/{a['trial_id']}/tell", json={"value": 2.0, "worker_id": "wa"})
    assert told.status_code == 200, told.text
    assert lease(http, "wc", task) is None  # nothing can reach rung 10 any more: b ends
    ended = trial(http, b)
    assert (ended["state"], ended["value"]) == ("pruned", 0.5)
    assert "budget" in ended["message"]
    info = http.get(f"/api/v1/studies/{study}").json()
    assert (info["state"], info["n_complete"], info["n_pruned"], info["n_paused"]) == (
        "complete",
        1,
        1,
        0,
    )


def test_only_asha_with_promotion_pauses_and_only_a_workers_trial(http: httpx.Client) -> None:
    plain = {"name": "asha", "options": {"min_resource": 10, "reduction_factor": 2}}
    create(http, managed(plain, max_trials=2, task="no-promotion"))
    first, second = lease(http, "wa", "no-promotion"), lease(http, "wb", "no-promotion")
    assert first is not None and second is not None
    report(http, first["trial_id"], "wa", 10, 1.0)
    assert report(http, second["trial_id"], "wb", 10, 0.5) == {
        "should_stop": True,
        "pause": False,
    }
    upload_checkpoint(http, second["trial_id"], "wb")
    refused = pause(http, second["trial_id"], "wb", 10)
    assert refused.status_code == 409 and "promotion" in refused.json()["detail"], refused.text
    assert trial(http, second["trial_id"])["state"] == "running"

    # An owner's asked trial has no worker to resume it: it is stopped, not paused.
    asked_study = create(http, {**managed(PROMOTION, max_trials=2), "task": None})
    asked = [
        http.post(f"/api/v1/studies/{asked_study}/ask", json={"count": 1}).json()["trials"][0]
        for _ in range(2)
    ]
    answers = [
        http.post(f"/api/v1/trials/{t['id']}/report", json={"step": 10, "value": v}).json()
        for t, v in zip(asked, (1.0, 0.5), strict=True)
    ]
    assert answers[1] == {"should_stop": True, "pause": False}, answers


def test_only_the_lease_holders_token_pauses(
    secured: ServerProcess, token: Callable[..., str]
) -> None:
    tokens = [token("user", "owner"), token("worker", "holder"), token("worker", "stranger")]
    as_user, holder, stranger = (
        httpx.Client(
            base_url=secured.url,
            headers={"Authorization": f"Bearer {token}", **SDK_HEADERS},
            timeout=30,
            verify=False,
        )
        for token in tokens
    )
    with as_user, holder, stranger:
        create(as_user, managed(PROMOTION, max_trials=2, task="holders"))
        first, second = lease(holder, "w1", "holders"), lease(holder, "w2", "holders")
        assert first is not None and second is not None
        report(holder, first["trial_id"], "w1", 10, 1.0)
        assert report(holder, second["trial_id"], "w2", 10, 0.5)["pause"] is True
        upload_checkpoint(holder, second["trial_id"], "w2")
        stolen = pause(stranger, second["trial_id"], "w2", 10)
        assert stolen.status_code == 403, stolen.text
        nameless = stranger.post(f"/api/v1/trials/{second['trial_id']}/pause", json={"step": 10})
        assert nameless.status_code == 422 and "worker_id" in nameless.text
        assert trial(holder, second["trial_id"])["state"] == "running"
        assert pause(holder, second["trial_id"], "w2", 10).status_code == 200


def test_the_sweeper_ends_paused_trials_of_a_spent_study_without_any_worker_asking(
    server_factory: Callable[..., ServerProcess],
) -> None:
    """The last running trial is told, not paused: no report can reach the rung any
    more, and with no worker polling for work the server's own sweep ends the wait."""
    server = server_factory(AD_SWEEP_SECONDS="0.2")
    with httpx.Client(base_url=server.url, headers=SDK_HEADERS, timeout=30, verify=False) as http:
        study = create(http, managed(PROMOTION, max_trials=2))
        a = lease(http, "wa")
        assert a is not None
        report(http, a["trial_id"], "wa", 10, 1.0)
        b = paused_at_rung(http, "wb", 0.5)
        told = http.post(
            f"/api/v1/trials/{a['trial_id']}/tell", json={"value": 2.0, "worker_id": "wa"}
        )
        assert told.status_code == 200, told.text
        for _ in range(300):  # no lease from here on: only the sweeper can settle b
            if trial(http, b)["state"] != "paused":
                break
            time.sleep(0.1)
        ended = trial(http, b)
        assert (ended["state"], ended["value"]) == ("pruned", 0.5)
        info = http.get(f"/api/v1/studies/{study}").json()
        assert (info["state"], info["n_pruned"], info["n_paused"]) == ("complete", 1, 0)


def test_only_a_workers_checkpoint_of_the_pausing_lease_is_resumed_from(
    secured: ServerProcess, token: Callable[..., str]
) -> None:
    """Issue 36: the study's owner leases a job with its user token, uploads a
    checkpoint under that lease and pauses the trial (taken: it did reach the rung);
    a worker whose checkpoint was uploaded under an earlier lease of its trial (before
    it gave the lease back) may not pause on it until it uploads again. Promoted, the
    owner's trial goes out without a resume point (the worker trains it from scratch);
    the worker's resumes from its checkpoint."""
    task = "issue-36"  # this test's own on the shared server
    owner, worker = (
        httpx.Client(
            base_url=secured.url,
            headers={"Authorization": f"Bearer {token(*role)}", **SDK_HEADERS},
            timeout=30,
            verify=False,
        )
        for role in (("user", "owner"), ("worker", "holder"))
    )
    with owner, worker:
        create(owner, managed(PROMOTION, max_trials=6, task=task))
        a = lease(worker, "wa", task)
        assert a is not None
        report(worker, a["trial_id"], "wa", 10, 1.0)
        users = paused_at_rung(owner, "u", 0.5, task)

        retried = lease(worker, "wc", task)
        assert retried is not None
        upload_checkpoint(worker, retried["trial_id"], "wc")
        given_back = {"worker_id": "wc"}
        released = worker.post(f"/api/v1/trials/{retried['trial_id']}/release", json=given_back)
        assert released.status_code == 200, released.text
        again = lease(worker, "wc", task)
        assert again is not None and again["trial_id"] == retried["trial_id"]
        assert report(worker, retried["trial_id"], "wc", 10, 0.45)["pause"] is True
        stale = pause(worker, retried["trial_id"], "wc", 10)
        assert stale.status_code == 409 and "under this lease" in stale.text, stale.text
        upload_checkpoint(worker, retried["trial_id"], "wc")
        assert pause(worker, retried["trial_id"], "wc", 10).status_code == 200

        # Rung 10 at [1.0, 0.5, 0.45, 0.1]: the top two go on, so the owner's trial.
        paused_at_rung(worker, "wd", 0.1, task)
        promoted = lease(worker, "we", task)
        assert promoted is not None and promoted["trial_id"] == users
        assert promoted["resume"] is None, promoted["resume"]
        # Six values: the top three go on, so the worker's.
        paused_at_rung(worker, "wf", 0.05, task)
        paused_at_rung(worker, "wg", 0.01, task)
        resumed = lease(worker, "wh", task)
        assert resumed is not None and resumed["trial_id"] == retried["trial_id"]
        assert resumed["resume"] == trial(worker, retried["trial_id"])["checkpoint"]
        assert resumed["resume"]["lease"] == 2
