"""Stopping a study from its page (issue 62), in a real headless Chromium against a real
``adserver``: the Stop button is there for whoever may stop the study (anyone with auth
off; its owner or an admin with auth on), never for a reader or another user; it asks
first, calls ``POST /api/v1/studies/{id}/stop``, and the page shows the study stopped."""

from __future__ import annotations

from collections.abc import Callable

import httpx
import pytest

from adclient.testing.servers import SDK_HEADERS, ServerProcess, make_token
from tests.service.chromium import Chromium
from tests.service.dashboard_pages import MANAGED_BOX, STUDY_PAGE_READY
from tests.service.dashboard_pages import sign_in as dashboard_sign_in

pytestmark = [
    pytest.mark.browser,
    pytest.mark.e2e,
    pytest.mark.xdist_group("browser"),
    # Stopping and who may, on PostgreSQL: test_ownership_e2e, on both.
    pytest.mark.parametrize("database", ["sqlite"]),
]

STOP = "document.querySelector('[data-stop]')"
STOP_DIALOG = "document.querySelector('[data-stop-dialog]')"


def state_badge(browser: Chromium) -> str:
    return str(browser.evaluate("document.querySelector('[data-state]').textContent.trim()"))


def test_stop_asks_first_then_stops_and_the_page_shows_it(
    live_server: ServerProcess, browser: Chromium
) -> None:
    with httpx.Client(base_url=live_server.url, headers=SDK_HEADERS, timeout=30) as http:
        study = http.post("/api/v1/studies", json={**MANAGED_BOX, "name": "to stop"}).json()["id"]
        job = http.post("/api/v1/jobs/lease", json={"worker_id": "w"}).json()
        assert job["study_id"] == study
        queued = http.post(
            f"/api/v1/studies/{study}/trials", json={"params": {"x": 0.25, "y": 0.5, "z": 0.75}}
        )
        assert queued.status_code == 201, queued.text

        browser.navigate(f"{live_server.url}/#/studies/{study}")
        browser.wait_for(STUDY_PAGE_READY)
        assert state_badge(browser) == "running"
        assert browser.evaluate(f"{STOP}.hidden") is False
        browser.evaluate(f"{STOP}.click()")
        assert browser.evaluate(f"{STOP_DIALOG}.open") is True
        question = browser.evaluate("document.querySelector('[data-stop-question]').textContent")
        assert "“to stop” (#" in question
        assert "1 queued trials are dropped as failed" in question
        assert "1 running trials may still be told" in question
        browser.evaluate("document.querySelector('[data-stop-cancel]').click()")
        browser.wait_for(f"!{STOP_DIALOG}.open")
        assert http.get(f"/api/v1/studies/{study}").json()["state"] == "running"

        browser.evaluate(f"{STOP}.click()")
        browser.evaluate("document.querySelector('[data-stop-confirm]').click()")
        browser.wait_for(
            f"!{STOP_DIALOG}.open && {STOP}.hidden"
            " && document.querySelector('[data-state]').textContent.trim() === 'stopped'"
        )
        stopped = http.get(f"/api/v1/studies/{study}").json()
        assert (stopped["state"], stopped["n_queued"], stopped["n_running"]) == ("stopped", 0, 1)
        # The rest of the page follows on its next poll: the queued trial failed.
        browser.wait_for(
            "[...document.querySelectorAll('[data-trials] tbody tr[data-trial-id]')]"
            ".some(row => row.cells[1].textContent.includes('failed'))"
        )
    assert browser.errors == []


def test_only_those_who_may_stop_get_the_button(
    server_factory: Callable[..., ServerProcess], browser: Chromium
) -> None:
    server = server_factory(AD_AUTH="true")
    owner = make_token(server, "user", name="olga")
    other = make_token(server, "user", name="pavel")
    reader = make_token(server, "reader")
    headers = {**SDK_HEADERS, "Authorization": f"Bearer {owner}"}
    with httpx.Client(base_url=server.url, headers=headers, timeout=30) as http:
        study = http.post("/api/v1/studies", json={**MANAGED_BOX, "name": "olga's"}).json()["id"]

    def sign_in(token: str) -> None:
        dashboard_sign_in(browser, f"{server.url}/#/studies/{study}", token)

    for token in (reader, other):
        sign_in(token)
        assert state_badge(browser) == "running"
        assert browser.evaluate(f"{STOP}.hidden") is True
        browser.evaluate("document.querySelector('[data-sign-out]').click()")

    sign_in(owner)
    assert browser.evaluate(f"{STOP}.hidden") is False
    browser.evaluate(f"{STOP}.click()")
    browser.evaluate("document.querySelector('[data-stop-confirm]').click()")
    browser.wait_for(f"{STOP}.hidden && !{STOP_DIALOG}.open")
    assert state_badge(browser) == "stopped"
    with httpx.Client(base_url=server.url, headers=headers, timeout=30) as http:
        assert http.get(f"/api/v1/studies/{study}").json()["state"] == "stopped"
