"""Leases by ownership (issue 58, finding 5): a ``user`` token leases only the trials of
studies it created, queued ones and newly proposed ones alike; a ``worker`` or ``admin``
token any managed study's; a reader none. A real server with auth on, tokens made by
``adserver token create``."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Any

import httpx
import pytest

from adclient.testing.servers import ServerProcess
from tests.service.test_ownership_e2e import as_token, token

__all__ = ["token"]  # the tokens of the module's server with auth on (conftest's secured)

pytestmark = [pytest.mark.e2e, pytest.mark.xdist_group("lease-ownership")]


def managed(task: str, **fields: Any) -> dict[str, Any]:
    """A managed study of its own ``task``: leasing ``[task]`` takes only its jobs."""
    return {
        "name": task,
        "space": {"type": "box", "params": [{"name": "x", "low": 0, "high": 1}]},
        "proposer": {"name": "random"},
        "task": {"name": task, "external": True},
        "max_trials": 20,
        **fields,
    }


@pytest.fixture(scope="module")
def as_role(
    secured: ServerProcess, token: Callable[..., str]
) -> Iterator[Callable[..., httpx.Client]]:
    """``as_role(role, name="")``: a client with the token of that role and name."""
    clients: dict[tuple[str, str], httpx.Client] = {}

    def of(role: str, name: str = "") -> httpx.Client:
        if (role, name) not in clients:
            clients[role, name] = as_token(secured, token(role, name=name))
        return clients[role, name]

    yield of
    for client in clients.values():
        client.close()


def lease(api: httpx.Client, worker_id: str, tasks: list[str] | None = None) -> httpx.Response:
    body: dict[str, Any] = {"worker_id": worker_id}
    if tasks is not None:
        body["tasks"] = tasks
    return api.post("/api/v1/jobs/lease", json=body)


def test_a_user_token_leases_and_tells_only_its_own_studies_trials(
    as_role: Callable[..., httpx.Client],
) -> None:
    """The issue's probe: bob's user token leased a trial of alice's study and told it
    1e300, which became her study's best. Now bob's lease of her task finds no work,
    whether her study has a queued trial or would propose one, while bob's and alice's
    own leases are served and a worker's too; her study's best is her own tell's."""
    alice, bob = as_role("user", "alice"), as_role("user", "bob")
    study = alice.post("/api/v1/studies", json=managed("alices-task")).json()
    enqueued = alice.post(f"/api/v1/studies/{study['id']}/trials", json={"params": {"x": 0.5}})
    assert enqueued.status_code == 201, enqueued.text

    for _ in range(2):  # her queued trial, then a new proposal: neither is bob's
        refused = lease(bob, "bob", ["alices-task"])
        assert refused.status_code == 204, refused.text
    queued = lease(alice, "alice", ["alices-task"])
    assert queued.status_code == 200 and queued.json()["params"] == {"x": 0.5}
    proposed = lease(alice, "alice", ["alices-task"])
    assert proposed.status_code == 200 and proposed.json()["study_id"] == study["id"]
    assert lease(bob, "bob", ["alices-task"]).status_code == 204

    # Bob cannot tell a trial of hers, nor any other lease-bound action, even naming
    # her worker id; her own tell stands.
    trial = f"/api/v1/trials/{queued.json()['trial_id']}"
    told = bob.post(trial + "/tell", json={"worker_id": "alice", "value": 1e300})
    assert told.status_code == 403, told.text
    assert (
        alice.post(trial + "/tell", json={"worker_id": "alice", "value": 0.25}).status_code == 200
    )
    best = alice.get(f"/api/v1/studies/{study['id']}").json()
    assert best["best_value"] == 0.25, best

    # A lease without a task filter serves bob his own study, not her older one.
    own = bob.post("/api/v1/studies", json=managed("bobs-task")).json()
    mine = lease(bob, "bob")
    assert mine.status_code == 200 and mine.json()["study_id"] == own["id"], mine.text
    worker = lease(as_role("worker"), "w", ["alices-task"])
    assert worker.status_code == 200 and worker.json()["study_id"] == study["id"]


@pytest.mark.parametrize(
    ("role", "name", "answer"),
    [
        ("reader", "", 403),
        ("worker", "", 200),
        ("user", "owner", 200),
        ("user", "stranger", 204),
        ("admin", "", 200),
    ],
)
def test_who_may_lease_a_users_study(
    as_role: Callable[..., httpx.Client], role: str, name: str, answer: int
) -> None:
    """docs/security.md's role table: a reader leases nothing, a worker and an admin
    any managed study's trials, a user only its own studies'."""
    task = f"roles-{role}-{name}"
    created = as_role("user", "owner").post("/api/v1/studies", json=managed(task))
    assert created.status_code == 201, created.text
    leased = lease(as_role(role, name), f"{role}-{name}", [task])
    assert leased.status_code == answer, leased.text
    if answer == 200:
        assert leased.json()["study_id"] == created.json()["id"]
    if answer == 403:
        assert "worker role" in leased.json()["detail"]


def test_lease_bound_actions_stay_with_the_token_that_leased(
    as_role: Callable[..., httpx.Client],
) -> None:
    """A worker's lease of a user's study: that user, owner of the study, still may not
    act on the lease (heartbeat, release, report, artifacts, user attributes, tell,
    pause, shared controller): each is 403 and the trial is untouched."""
    owner, worker = as_role("user", "carol"), as_role("worker", "carols-worker")
    owner.post("/api/v1/studies", json=managed("carols-task", pruner={"name": "none"}))
    job = lease(worker, "w", ["carols-task"]).json()
    trial = f"/api/v1/trials/{job['trial_id']}"
    before = owner.get(trial).json()
    named = {"worker_id": "w"}
    for method, path, body in (
        ("POST", "/heartbeat", named),
        ("POST", "/release", named),
        ("POST", "/report", {**named, "step": 1, "value": 1.0}),
        ("PATCH", "", {**named, "user_attrs": {"k": 1}}),
        ("POST", "/tell", {**named, "value": 1.0}),
        ("POST", "/pause", {**named, "step": 1}),
        ("POST", "/shared-controller", {**named, "base_version": None}),
    ):
        answer = owner.request(method, trial + path, json=body)
        assert answer.status_code == 403, (path, answer.text)
    upload = owner.put(trial + "/artifacts/robot.json?worker_id=w", content=b"{}")
    assert upload.status_code == 403, upload.text
    assert owner.get(trial).json() == before
    assert worker.post(trial + "/tell", json={**named, "value": 1.0}).status_code == 200
