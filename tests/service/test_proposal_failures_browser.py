"""The dashboard shows a study whose proposals fail (issue 36): its page says so and
why, as text; the studies list marks it. And one whose latest ask fell back to Sobol
points (issue 37): its page says why, and how many candidates did."""

from __future__ import annotations

from pathlib import Path

import httpx
import numpy as np
import pytest

from adclient.testing.servers import ServerProcess
from tests.failing_proposals import ERROR, design_study, unfit_representation, update_study
from tests.service.chromium import Chromium
from tests.service.dashboard_pages import STUDY_PAGE_READY

pytestmark = [pytest.mark.browser, pytest.mark.e2e, pytest.mark.xdist_group("browser")]

SHOWN = "document.querySelector('[data-proposal-error]')"
MARKUP = '<img src="x" onerror="window.ran = true"> <b>bold</b>'


def test_the_study_page_shows_a_failing_proposal_as_text(browser: Chromium, tmp_path: Path) -> None:
    server = ServerProcess(database_url=f"sqlite:///{tmp_path / 'studies.db'}", workdir=tmp_path)
    try:
        server.start()
        with httpx.Client(base_url=server.url, timeout=30) as http:
            failing = http.post("/api/v1/studies", json=design_study("failing")).json()["id"]
            good = http.post("/api/v1/studies", json=design_study("good")).json()["id"]
            unfit_representation(server.database_url, failing)
            assert http.post(f"/api/v1/studies/{failing}/ask", json={"count": 1}).status_code == 409

        browser.navigate(f"{server.url}/#/studies/{failing}")
        browser.wait_for(STUDY_PAGE_READY)
        assert browser.evaluate(f"{SHOWN}.hidden") is False
        text = browser.evaluate(f"{SHOWN}.textContent")
        assert text.startswith("Proposals failing (1 in a row; workers skip this study until ")
        assert ERROR in text

        browser.navigate(f"{server.url}/#/studies/{good}")
        browser.wait_for(f"{STUDY_PAGE_READY} && document.title.startsWith('good')")
        assert browser.evaluate(f"{SHOWN}.hidden") is True

        # An exception's message may quote what a user wrote: it stays text.
        update_study(server.database_url, failing, proposal_error=MARKUP)
        browser.navigate(f"{server.url}/#/studies/{failing}")
        browser.wait_for(f"{STUDY_PAGE_READY} && document.title.startsWith('failing')")
        assert browser.evaluate(f"{SHOWN}.textContent").endswith(f"): {MARKUP}")
        assert browser.evaluate(f"{SHOWN}.children.length") == 0
        assert browser.evaluate("window.ran === undefined") is True

        browser.navigate(f"{server.url}/#/")
        rows = browser.wait_for(
            "[...document.querySelectorAll('table.studies tbody tr')].map(r => r.textContent)"
        )
        marked = {row.split("#")[0].strip(): "proposals failing" in row for row in rows}
        assert marked == {"failing": True, "good": False}
        assert browser.errors == []
    finally:
        server.stop()


FALLBACK = "document.querySelector('[data-fallback]')"


def test_the_study_page_shows_a_fall_back_to_sobol_points(
    browser: Chromium, tmp_path: Path
) -> None:
    """3 MB per ask: 60 observations of 2 dimensions are over it, 12 are not."""
    server = ServerProcess(
        database_url=f"sqlite:///{tmp_path / 'studies.db'}",
        workdir=tmp_path,
        env={"AD_ASK_MEMORY_MB": "3"},
    )
    space = {"type": "box", "params": [{"name": n, "low": 0.0, "high": 1.0} for n in "xy"]}
    rng = np.random.default_rng(3)
    try:
        server.start()
        with httpx.Client(base_url=server.url, timeout=60) as http:
            ids = {}
            for name, n in (("large", 60), ("small", 12)):
                body = {"name": name, "space": space, "proposer": {"name": "qei"}}
                ids[name] = http.post("/api/v1/studies", json=body).json()["id"]
                known = [
                    {"params": {"x": a, "y": b}, "value": a - b} for a, b in rng.random((n, 2))
                ]
                assert http.post(f"/api/v1/studies/{ids[name]}/trials", json=known).is_success
                assert http.post(f"/api/v1/studies/{ids[name]}/ask", json={"count": 2}).is_success

        browser.navigate(f"{server.url}/#/studies/{ids['large']}")
        browser.wait_for(STUDY_PAGE_READY)
        assert browser.evaluate(f"{FALLBACK}.hidden") is False
        text = browser.evaluate(f"{FALLBACK}.textContent")
        assert text.startswith(
            "The latest ask fell back to Sobol points (2 candidates so far): memory budget: "
        ), text
        assert text.endswith("over the budget of 3 MB per ask")

        browser.navigate(f"{server.url}/#/studies/{ids['small']}")
        browser.wait_for(f"{STUDY_PAGE_READY} && document.title.startsWith('small')")
        assert browser.evaluate(f"{FALLBACK}.hidden") is True
        assert browser.errors == []
    finally:
        server.stop()
