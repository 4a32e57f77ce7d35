"""Trials the owner handed over are marked in the dashboard's trials table (a real
headless Chromium against a real ``adserver``; issue 16): enqueued and added ones say
so, proposed ones carry no mark."""

from __future__ import annotations

import httpx
import pytest

from adclient.testing.servers import SDK_HEADERS, ServerProcess
from tests.service.chromium import Chromium

pytestmark = [
    pytest.mark.browser,
    pytest.mark.e2e,
    pytest.mark.xdist_group("browser"),
    # The sources on PostgreSQL: test_dashboard_reads (the trials table's marks), on both.
    pytest.mark.parametrize("database", ["sqlite"]),
]


def test_enqueued_and_added_trials_are_marked(
    live_server: ServerProcess, browser: Chromium
) -> None:
    with httpx.Client(base_url=live_server.url, headers=SDK_HEADERS, timeout=30) as http:
        space = {"type": "box", "params": [{"name": "x", "low": 0, "high": 1}]}
        study = http.post("/api/v1/studies", json={"name": "handed", "space": space}).json()["id"]
        url = f"/api/v1/studies/{study}/trials"
        added = http.post(url, json={"params": {"x": 0.25}, "value": 1.0}).json()
        queued = http.post(url, json={"params": {"x": 0.75}}).json()
        asked = http.post(f"/api/v1/studies/{study}/ask", json={"count": 2}).json()["trials"]
    assert asked[0]["id"] == queued["id"]
    browser.navigate(f"{live_server.url}/#/studies/{study}")
    marks = browser.wait_for(
        "(() => { const rows = [...document.querySelectorAll('[data-trial-id]')];"
        " return rows.length === 3 ? Object.fromEntries(rows.map(row => [row.dataset.trialId,"
        " row.querySelector('[data-source]')?.textContent ?? null])) : null; })()"
    )
    assert marks == {
        str(added["id"]): "added",
        str(queued["id"]): "enqueued",
        str(asked[1]["id"]): None,
    }
