"""A study's learning curves: ``GET /api/v1/dashboard/studies/{id}/curves`` and the
dashboard's chart of them, in a real headless Chromium against a real ``adserver``
(issue 15): every trial that reported is a line, pruned ones counted apart; a page with
running trials redraws as new reports arrive."""

from __future__ import annotations

import httpx
import pytest

from adclient.testing.servers import SDK_HEADERS, ServerProcess
from tests.service.chromium import Chromium

pytestmark = [pytest.mark.browser, pytest.mark.e2e, pytest.mark.xdist_group("browser")]

SPACE = {"type": "box", "params": [{"name": "x", "low": 0, "high": 1}]}


def report(http: httpx.Client, trial_id: int, step: int, value: float) -> None:
    answer = http.post(f"/api/v1/trials/{trial_id}/report", json={"step": step, "value": value})
    assert answer.status_code == 200, answer.text


def test_curves_are_drawn_pruned_ones_apart_and_grow(
    live_server: ServerProcess, browser: Chromium
) -> None:
    with httpx.Client(base_url=live_server.url, headers=SDK_HEADERS, timeout=30) as http:
        study = http.post("/api/v1/studies", json={"name": "curves", "space": SPACE}).json()["id"]
        silent, done, pruned, running = (
            t["id"]
            for t in http.post(f"/api/v1/studies/{study}/ask", json={"count": 4}).json()["trials"]
        )
        for step, value in ((300, 0.5), (100, 0.1), (200, 0.3)):  # out of order on purpose
            report(http, done, step, value)
        report(http, pruned, 100, -0.2)
        report(http, running, 100, 0.05)
        http.post(f"/api/v1/trials/{done}/tell", json={"value": 0.6}).raise_for_status()
        http.post(f"/api/v1/trials/{pruned}/tell", json={"state": "pruned"}).raise_for_status()
        url = f"/api/v1/dashboard/studies/{study}/curves"
        curves = http.get(url).json()
        assert [(c["trial_id"], c["state"]) for c in curves["curves"]] == [
            (done, "complete"),
            (pruned, "pruned"),
            (running, "running"),
        ]  # the silent trial reported nothing: no curve
        assert curves["curves"][0]["steps"] == [100, 200, 300]
        assert curves["curves"][0]["values"] == [0.1, 0.3, 0.5]
        assert curves["more"] is False
        latest = http.get(url, params={"limit": 2}).json()
        assert [c["trial_id"] for c in latest["curves"]] == [pruned, running] and latest["more"]
        assert http.get(url, params={"limit": 0}).status_code == 422
        assert silent not in {c["trial_id"] for c in curves["curves"]}

        browser.navigate(f"{live_server.url}/#/studies/{study}")
        browser.wait_for("document.querySelector('.study')?.dataset.ready === 'true'")
        chart = "document.querySelector('canvas[data-curves]').dataset"
        drawn = f"[{chart}.curves, {chart}.pruned]"
        assert browser.wait_for(
            f"(() => {{ const d = {drawn}; return d[0] === '3' ? d : null; }})()"
        ) == ["3", "1"]
        # A report on a trial that had none: the next poll draws a fourth line.
        report(http, silent, 100, 0.2)
        assert browser.wait_for(f"{chart}.curves === '4'", timeout=30)
