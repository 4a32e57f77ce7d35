"""The dashboard shows a study whose proposals fail (issue 36): its page says so and
why, as text; the studies list marks it."""

from __future__ import annotations

from pathlib import Path

import httpx
import pytest

from tests.failing_proposals import ERROR, design_study, unfit_representation, update_study
from tests.servers import ServerProcess
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
