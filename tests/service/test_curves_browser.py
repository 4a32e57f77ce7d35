"""A study's learning curves on the dashboard, in a real headless Chromium against a real
``adserver`` (issue 15): every trial that reported is a line, pruned ones counted apart;
a page with running trials redraws as new reports arrive. What the chart reads, ``GET
/api/v1/dashboard/studies/{id}/curves``, tests/service/test_dashboard_reads.py asserts
on both databases."""

from __future__ import annotations

import httpx
import pytest

from adclient.testing.servers import SDK_HEADERS, ServerProcess
from tests.service.chromium import Chromium
from tests.service.dashboard_pages import seed_curves

pytestmark = [
    pytest.mark.browser,
    pytest.mark.e2e,
    pytest.mark.xdist_group("browser"),
    # The curves on PostgreSQL: test_dashboard_reads (learning curves), on both databases.
    pytest.mark.parametrize("database", ["sqlite"]),
]


def test_curves_are_drawn_pruned_ones_apart_and_grow(
    live_server: ServerProcess, browser: Chromium
) -> None:
    with httpx.Client(base_url=live_server.url, headers=SDK_HEADERS, timeout=30) as http:
        study, (silent, *_) = seed_curves(http)
        browser.navigate(f"{live_server.url}/#/studies/{study}")
        browser.wait_for("document.querySelector('.study')?.dataset.ready === 'true'")
        chart = "document.querySelector('canvas[data-curves]').dataset"
        drawn = f"[{chart}.curves, {chart}.pruned]"
        assert browser.wait_for(
            f"(() => {{ const d = {drawn}; return d[0] === '3' ? d : null; }})()"
        ) == ["3", "1"]
        # A report on a trial that had none: the next poll draws a fourth line.
        answer = http.post(f"/api/v1/trials/{silent}/report", json={"step": 100, "value": 0.2})
        assert answer.status_code == 200, answer.text
        assert browser.wait_for(f"{chart}.curves === '4'", timeout=30)
