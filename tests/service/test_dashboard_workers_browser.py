"""Issue 39 on the dashboard, in a real headless Chromium against a real ``adserver``: a
running managed study that no recent worker serves shows a warning card naming its
task and learner and the ``adworker`` to start (the server's ``GET
/studies/{id}/serving``, whose text ``adclient status`` prints), until a worker that
serves it comes; the studies list shows every worker the server has seen, with the
tasks and learners it named and its last contact. Workers are raw leases naming their
tasks and learners.

One server of its own for the module (SQLite; a worker leasing for any task would take
other modules' studies, and ``AD_UNSERVED_SECONDS=0`` flags an idle study at once
instead of after a minute) and one browser.
"""

from __future__ import annotations

import re
import sqlite3
from collections.abc import Iterator
from typing import Any

import httpx
import pytest

from adclient.testing.servers import ServerProcess
from tests.service.chromium import Chromium
from tests.service.dashboard_pages import MANAGED_BOX, STUDY_PAGE_READY, tell

pytestmark = [pytest.mark.browser, pytest.mark.e2e, pytest.mark.xdist_group("browser")]

CARD = "document.querySelector('[data-unserved]')"
WORKER_ROWS = (
    "[...document.querySelectorAll('[data-server-workers] tr[data-worker]')].map(row =>"
    " [row.dataset.worker, row.querySelector('[data-worker-tasks]').textContent,"
    " row.querySelector('[data-worker-learners]').textContent, row.cells[2].textContent])"
)


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    workdir = tmp_path_factory.mktemp("workers-panel")
    process = ServerProcess(
        database_url=f"sqlite:///{workdir / 'studies.db'}",
        workdir=workdir,
        env={"AD_UNSERVED_SECONDS": "0"},
    ).start()
    yield process
    process.stop()


def lease(http: httpx.Client, worker: str, **serves: list[str]) -> dict[str, Any] | None:
    """A raw lease naming the worker's tasks and learners: the job, or None (no work)."""
    response = http.post("/api/v1/jobs/lease", json={"worker_id": worker, **serves})
    assert response.status_code in (200, 204), response.text
    return dict(response.json()) if response.status_code == 200 else None


def test_a_study_no_worker_serves_says_so_until_one_does(
    server: ServerProcess, browser: Chromium, http: httpx.Client
) -> None:
    body = {**MANAGED_BOX, "name": "unserved", "task": {"name": "reach-point", "external": True}}
    study = http.post("/api/v1/studies", json=body).raise_for_status().json()
    assert lease(http, "other-sim", tasks=["other-sim"]) is None
    assert lease(http, "no-fast", tasks=["reach-point"], learners=["ppo"]) is None
    serving = http.get(f"/api/v1/studies/{study['id']}/serving").json()
    assert (serving["serving"], serving["others"], serving["unserved"]) == (0, 2, True)

    browser.navigate(f"{server.url}/#/studies/{study['id']}")
    browser.wait_for(STUDY_PAGE_READY)
    browser.wait_for(f"!{CARD}.hidden")
    heading = browser.evaluate(f"{CARD}.querySelector('h2').textContent")
    assert heading == "No worker serves task reach-point with learner fast"
    text = browser.evaluate(f"{CARD}.querySelector('[data-unserved-text]').textContent")
    assert text == serving["text"]  # the sentence adclient status prints
    assert "none serving task 'reach-point' with learner 'fast' seen in the last 90 s" in text
    assert "(2 other workers serve other tasks or learners)" in text
    assert f"adworker --server {server.url} --function MODULE:FUNCTION --task reach-point" in text

    # A worker that serves it: it takes a trial and tells it; the study is idle again,
    # but served, and the card goes.
    job = lease(http, "reach-sim", tasks=["reach-point"], learners=["fast"])
    assert job is not None and job["study_id"] == study["id"]
    tell(http, job["trial_id"], value=0.5)
    serving = http.get(f"/api/v1/studies/{study['id']}/serving").json()
    assert (serving["serving"], serving["unserved"]) == (1, False)
    assert serving["idle_seconds"] is not None  # nothing runs: only the worker keeps it served
    browser.wait_for(f"{CARD}.hidden")
    assert browser.errors == []


def test_the_studies_list_shows_every_worker_with_its_tasks_and_learners(
    server: ServerProcess, browser: Chromium, http: httpx.Client
) -> None:
    assert lease(http, "picky", tasks=["walk-forward", "stand-up"], learners=["ppo"]) is None
    assert lease(http, "any-learner", tasks=["other-sim"]) is None
    browser.navigate(f"{server.url}/#/")
    browser.wait_for(f"{WORKER_ROWS}.length >= 2")
    rows = {row[0]: row[1:] for row in browser.evaluate(WORKER_ROWS)}
    assert rows["picky"][:2] == ["stand-up, walk-forward", "ppo"]
    assert rows["any-learner"][:2] == ["other-sim", "any"]
    assert re.fullmatch(r"just now|\d+ s ago", rows["picky"][2])  # last contact
    assert browser.errors == []


def test_a_worker_not_heard_from_lately_is_gone_not_idle(
    server: ServerProcess, browser: Chromium, http: httpx.Client
) -> None:
    """A stopped adworker says nothing as it exits: one the server has not heard from in
    its last 90 s is ``gone`` in GET /workers and on the dashboard, whatever it held
    (its row's last contact backdated an hour in the server's SQLite file); one heard
    from is idle, or working while it holds a trial."""
    body = {**MANAGED_BOX, "name": "gone", "task": {"name": "gone-sim", "external": True}}
    study = http.post("/api/v1/studies", json=body).raise_for_status().json()
    assert lease(http, "stopped-sim", tasks=["other-gone-sim"]) is None
    assert lease(http, "killed-sim", tasks=["gone-sim"], learners=["fast"]) is not None
    assert lease(http, "waiting-sim", tasks=["other-gone-sim"]) is None
    assert lease(http, "busy-sim", tasks=["gone-sim"], learners=["fast"]) is not None
    database = server.database_url.removeprefix("sqlite:///")
    with sqlite3.connect(database) as db:
        db.execute(
            "UPDATE workers SET last_seen_at = datetime(last_seen_at, '-1 hour') "
            "WHERE worker_id IN ('stopped-sim', 'killed-sim')"
        )
    states = {w["worker_id"]: w["state"] for w in http.get("/api/v1/workers").json()}
    assert {name: states[name] for name in ("stopped-sim", "killed-sim")} == {
        "stopped-sim": "gone",
        "killed-sim": "gone",
    }
    assert (states["waiting-sim"], states["busy-sim"]) == ("idle", "working")
    listed = http.get(f"/api/v1/studies/{study['id']}/workers").json()
    assert {w["worker_id"]: w["state"] for w in listed} == {
        "killed-sim": "gone",
        "busy-sim": "working",
    }

    lease_cells = (
        "Object.fromEntries([...document.querySelectorAll('{table} tr[data-worker]')]"
        ".map(row => [row.dataset.worker, row.cells[1].textContent.trim()]))"
    )
    browser.navigate(f"{server.url}/#/")
    browser.wait_for(f"{WORKER_ROWS}.some(row => row[0] === 'busy-sim')")
    cells = browser.evaluate(lease_cells.format(table="[data-server-workers]"))
    assert (cells["stopped-sim"], cells["killed-sim"]) == ("gone", "gone")
    assert cells["waiting-sim"] == "idle" and cells["busy-sim"].startswith("trial id ")

    browser.navigate(f"{server.url}/#/studies/{study['id']}")
    browser.wait_for(STUDY_PAGE_READY)
    browser.wait_for("document.querySelectorAll('[data-workers] tr[data-worker]').length === 2")
    cells = browser.evaluate(lease_cells.format(table="[data-workers]"))
    assert cells["killed-sim"] == "gone" and cells["busy-sim"].startswith("trial #")
    assert browser.errors == []
