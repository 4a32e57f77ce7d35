"""Issue 58 on a real ``adserver`` with auth on (a plain ``user`` token creates and asks,
a ``worker`` token leases): what a template study's expansions may store, per URDF, per
ask and per study; and a template study whose expansions fail, or run slow, between
its check points backs off as a failed proposal does, without holding other studies'
leases."""

from __future__ import annotations

import statistics
import time
from collections.abc import Iterator
from typing import Any

import httpx
import pytest

from adclient.testing.servers import ServerProcess, make_token
from tests.picky_template import JOINTED

pytestmark = pytest.mark.e2e

XACRO = 'xmlns:xacro="http://www.ros.org/wiki/xacro"'
BASE = (
    '<link name="base"><visual><geometry><box size="${size} 0.1 0.1"/></geometry></visual></link>'
)
BETWEEN = "${size != 0.1 and size != 0.2 and size != 0.3}"
"""True at every size but 0.1, 0.2 and 0.3: the low, middle and high the server checks."""
LIMITS = {
    "AD_MAX_URDF_BYTES": "100000",
    "AD_MAX_ASK_URDF_BYTES": "160000",
    "AD_MAX_STUDY_URDF_BYTES": "200000",
    "AD_LEASE_EXPAND_SECONDS": "0.5",
}
"""A URDF of the macro template (74 kB) fits, two of them an ask, three a study."""


@pytest.fixture(scope="module")
def secured(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    workdir = tmp_path_factory.mktemp("template-budgets")
    server = ServerProcess(
        database_url=f"sqlite:///{workdir / 'studies.db'}",
        workdir=workdir,
        env={"AD_AUTH": "1", **LIMITS},
    )
    yield server.start()
    server.stop()


def client(server: ServerProcess, role: str) -> httpx.Client:
    return httpx.Client(
        base_url=server.url,
        headers={"Authorization": f"Bearer {make_token(server, role, name=role)}"},
        timeout=120,
        verify=False,
    )


@pytest.fixture(scope="module")
def user(secured: ServerProcess) -> Iterator[httpx.Client]:
    with client(secured, "user") as http:
        yield http


@pytest.fixture(scope="module")
def worker(secured: ServerProcess) -> Iterator[httpx.Client]:
    with client(secured, "worker") as http:
        yield http


def macro_template(calls: int) -> str:
    """The issue's template at a hundredth of its body: a macro of twelve ``<gazebo>``
    elements (770 bytes, where the issue's was 100 kB) expanded ``calls`` times."""
    unit = '<gazebo reference="base"><sensor name="s" type="ray"/></gazebo>'
    return (
        f'<robot name="big" {XACRO}><xacro:macro name="m">{unit * 12}</xacro:macro>{BASE}'
        f"{JOINTED}{'<xacro:m/>' * calls}</robot>"
    )


def study(
    user: httpx.Client, name: str, template: str, task: str | None = None, **fields: Any
) -> int:
    body: dict[str, Any] = {
        "name": name,
        "space": {
            "type": "template",
            "template": template,
            "params": [{"name": "size", "low": 0.1, "high": 0.3}],
        },
        "proposer": {"name": "random", "seed": 4},
        **fields,
    }
    if task is not None:
        body.update(task={"name": task, "external": True}, max_trials=100)
    created = user.post("/api/v1/studies", json=body)
    assert created.status_code == 201, created.text
    return int(created.json()["id"])


def ask(user: httpx.Client, study_id: int, count: int) -> list[dict[str, Any]]:
    asked = user.post(f"/api/v1/studies/{study_id}/ask", json={"count": count})
    assert asked.status_code == 200, asked.text
    trials: list[dict[str, Any]] = asked.json()["trials"]
    return trials


def test_the_macro_templates_urdfs_are_bounded_per_urdf_per_ask_and_per_study(
    user: httpx.Client, worker: httpx.Client
) -> None:
    """Before issue 58, two asks of 40 trials stored 40 URDFs of 8.3 MB each: now a
    template whose URDF is over AD_MAX_URDF_BYTES is refused at creation, an ask's
    URDFs past AD_MAX_ASK_URDF_BYTES fail, the trials past AD_MAX_STUDY_URDF_BYTES fail,
    and a study that stores its limit gets no new trial: its ask is a 409, leases
    skip it. Each refusal names its limit and setting."""
    refused = user.post(
        "/api/v1/studies",
        json={
            "name": "too-big",
            "space": {
                "type": "template",
                "template": macro_template(166),
                "params": [{"name": "size", "low": 0.1, "high": 0.3}],
            },
        },
    )
    assert refused.status_code == 422, refused.text
    assert "over the limit of 100,000 bytes (AD_MAX_URDF_BYTES)" in refused.json()["detail"]

    study_id = study(user, "macro", macro_template(83), task="macro-task")
    first = ask(user, study_id, 3)
    assert [trial["state"] for trial in first] == ["running", "running", "failed"], first
    assert "the limit of 160,000 bytes per ask (AD_MAX_ASK_URDF_BYTES)" in first[2]["message"]
    second = ask(user, study_id, 3)
    assert [trial["state"] for trial in second] == ["running", "failed", "failed"], second
    assert "the limit of 200,000 bytes per study (AD_MAX_STUDY_URDF_BYTES)" in second[1]["message"]
    assert "(AD_MAX_" in second[2]["message"]  # past the ask's limit too
    full = user.post(f"/api/v1/studies/{study_id}/ask", json={"count": 1})
    assert full.status_code == 409, full.text
    detail = full.json()["detail"]
    assert "the limit of 200,000 bytes per study (AD_MAX_STUDY_URDF_BYTES)" in detail, detail
    assert user.get(f"/api/v1/studies/{study_id}").json()["n_trials"] == 6  # none stored
    leased = worker.post("/api/v1/jobs/lease", json={"worker_id": "w", "tasks": ["macro-task"]})
    assert leased.status_code == 204, leased.text


def slow_between(doublings: int) -> str:
    """A robot that expands at once at its check points and slowly between them:
    ``2**doublings`` calls of an empty macro (macros that each call the one before
    twice), which add nothing to the URDF."""
    macros = ['<xacro:macro name="m0"></xacro:macro>']
    macros += [
        f'<xacro:macro name="m{i}"><xacro:m{i - 1}/><xacro:m{i - 1}/></xacro:macro>'
        for i in range(1, doublings + 1)
    ]
    slow = f'<xacro:if value="{BETWEEN}"><xacro:m{doublings}/></xacro:if>'
    return f'<robot name="slow" {XACRO}>{"".join(macros)}{BASE}{JOINTED}{slow}</robot>'


BROKEN_BETWEEN = (
    f'<robot name="broken" {XACRO}>{BASE}{JOINTED}<xacro:if value="{BETWEEN}">'
    '<joint name="loose" type="fixed"><parent link="base"/><child link="nowhere"/></joint>'
    "</xacro:if></robot>"
)
"""A robot at its check points, a joint to no link between them."""


def ordinary(user: httpx.Client, task: str) -> int:
    body = {
        "name": f"ordinary-{task}",
        "space": {"type": "box", "params": [{"name": "x", "low": 0, "high": 1}]},
        "proposer": {"name": "random", "seed": 5},
        "task": {"name": task, "external": True},
        "max_trials": 100,
    }
    created = user.post("/api/v1/studies", json=body)
    assert created.status_code == 201, created.text
    return int(created.json()["id"])


def timed_lease(worker: httpx.Client, tasks: list[str]) -> tuple[float, dict[str, Any]]:
    started = time.perf_counter()
    leased = worker.post("/api/v1/jobs/lease", json={"worker_id": "w", "tasks": tasks})
    seconds = time.perf_counter() - started
    assert leased.status_code == 200, leased.text
    job: dict[str, Any] = leased.json()
    return seconds, job


def test_a_study_expanding_slowly_between_its_check_points_backs_off_off_the_lease_path(
    user: httpx.Client, worker: httpx.Client
) -> None:
    """The slow study is the older, so a lease tries it first. Before, every lease
    waited for its expansion (about 21 s for the issue's) and got its trial; now the
    first lease waits AD_LEASE_EXPAND_SECONDS at most and gets the ordinary study's
    trial, the slow one backs off (said on the study) while its expansion goes on and
    stores the URDF for its trial, back in the queue; the leases after are as fast as
    leases of the ordinary study alone (medians of the same run)."""
    slow_id = study(user, "slow", slow_between(14), task="slow-task")
    ordinary_id = ordinary(user, "ordinary-task")
    quiet = [timed_lease(worker, ["ordinary-task"])[0] for _ in range(8)]
    _, first = timed_lease(worker, ["slow-task", "ordinary-task"])
    assert first["study_id"] == ordinary_id

    slow = user.get(f"/api/v1/studies/{slow_id}").json()
    assert slow["proposal_failures"] == 1 and slow["proposal_retry_at"] is not None, slow
    assert "took over 0.5 s (AD_LEASE_EXPAND_SECONDS)" in slow["proposal_error"], slow
    (trial,) = user.get(f"/api/v1/studies/{slow_id}/trials").json()
    assert trial["state"] == "queued", trial
    deadline = time.monotonic() + 60
    while (served := user.get(f"/api/v1/trials/{trial['id']}/urdf")).status_code != 200:
        assert time.monotonic() < deadline, served.text
        time.sleep(0.25)
    assert 'link name="arm"' in served.text
    assert user.get(f"/api/v1/trials/{trial['id']}").json()["state"] == "queued"

    # the expansion done (its CPU no longer shared), the study still backs off
    mixed = [timed_lease(worker, ["slow-task", "ordinary-task"]) for _ in range(8)]
    assert [job["study_id"] for _, job in mixed] == [ordinary_id] * 8
    ratio = statistics.median(seconds for seconds, _ in mixed) / statistics.median(quiet)
    assert ratio < 3, (mixed, quiet)


def test_a_study_whose_expansions_fail_between_its_check_points_backs_off(
    user: httpx.Client, worker: httpx.Client
) -> None:
    """Before, each failed expansion was a failed trial and nothing more: every lease
    proposed for the study again. Now the first failure backs the study off (said on
    it, naming the trial and why), and the leases after go to the other study."""
    broken_id = study(user, "broken", BROKEN_BETWEEN, task="broken-task")
    ordinary_id = ordinary(user, "other-task")
    jobs = [timed_lease(worker, ["broken-task", "other-task"])[1] for _ in range(5)]
    assert [job["study_id"] for job in jobs] == [ordinary_id] * 5
    # on a loaded machine the first lease may stop waiting for the expansion (a nice 19
    # child) before it fails: the failure is then said on the study when it is known
    deadline = time.monotonic() + 60
    while (trial := user.get(f"/api/v1/studies/{broken_id}/trials").json()[0])["state"] != (
        "failed"
    ) or "took over" in user.get(f"/api/v1/studies/{broken_id}").json()["proposal_error"]:
        assert time.monotonic() < deadline, trial
        time.sleep(0.1)
    assert "its child 'nowhere' is no link" in trial["message"]
    broken = user.get(f"/api/v1/studies/{broken_id}").json()
    assert broken["proposal_failures"] == 1 and broken["proposal_retry_at"] is not None
    assert f"trial {trial['id']}: the template does not expand" in broken["proposal_error"]


SLOW_AND_BROKEN = slow_between(14).replace(
    "</xacro:if></robot>",
    '</xacro:if><xacro:if value="' + BETWEEN + '"><joint name="loose" type="fixed">'
    '<parent link="base"/><child link="nowhere"/></joint></xacro:if></robot>',
)
"""Slow between its check points (as ``slow_between``), and a joint to no link there."""


def test_a_failure_found_after_the_lease_stopped_waiting_is_said_on_the_study(
    user: httpx.Client, worker: httpx.Client
) -> None:
    """The lease stops waiting (the study backs off: "took over"); when the expansion
    then fails, the study says why instead, the same failure in a row, not one more."""
    assert SLOW_AND_BROKEN.count("nowhere") == 1
    slow_id = study(user, "slow-broken", SLOW_AND_BROKEN, task="slow-broken-task")
    ordinary_id = ordinary(user, "another-task")
    _, first = timed_lease(worker, ["slow-broken-task", "another-task"])
    assert first["study_id"] == ordinary_id
    said = user.get(f"/api/v1/studies/{slow_id}").json()
    assert "took over 0.5 s (AD_LEASE_EXPAND_SECONDS)" in said["proposal_error"], said
    deadline = time.monotonic() + 60
    while "took over" in (said := user.get(f"/api/v1/studies/{slow_id}").json())["proposal_error"]:
        assert time.monotonic() < deadline, said
        time.sleep(0.1)
    (trial,) = user.get(f"/api/v1/studies/{slow_id}/trials").json()
    assert trial["state"] == "failed" and "its child 'nowhere' is no link" in trial["message"]
    assert f"trial {trial['id']}: the template does not expand" in said["proposal_error"]
    assert said["proposal_failures"] == 1 and said["proposal_retry_at"] is not None
