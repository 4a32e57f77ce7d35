"""Issue 39: the dashboard's page of a study of one design shows how its repeats spread
(a card of each objective's repeats, mean, std, min, median and max), kept current as
repeats finish; a study that searches has no such card."""

from __future__ import annotations

import statistics
from pathlib import Path

import httpx
import pytest
import yaml

from adclient.testing.servers import ServerProcess
from tests.service.chromium import Chromium
from tests.service.dashboard_pages import EXAMPLES, STUDY_PAGE_READY

pytestmark = [pytest.mark.browser, pytest.mark.e2e, pytest.mark.xdist_group("browser")]

CARD = "document.querySelector('[data-spread-card]')"
CELLS = f"[...{CARD}.querySelectorAll('tbody tr > *')].map(cell => cell.textContent)"


def test_the_study_page_of_one_design_shows_the_spread_of_its_repeats(
    browser: Chromium, tmp_path: Path
) -> None:
    body = yaml.safe_load((EXAMPLES / "one-design.yaml").read_text())
    del body["task"]  # told by hand
    searching = yaml.safe_load((EXAMPLES / "stand-up.yaml").read_text()) | {"task": None}
    server = ServerProcess(database_url=f"sqlite:///{tmp_path / 'studies.db'}", workdir=tmp_path)
    try:
        server.start()
        with httpx.Client(base_url=server.url, timeout=60) as http:
            study = http.post("/api/v1/studies", json=body).json()["id"]
            other = http.post("/api/v1/studies", json=searching).json()["id"]
            trials = http.post(f"/api/v1/studies/{study}/ask", json={"count": 3}).json()["trials"]
            values = [0.5, 0.25, 1.0]
            for trial, value in zip(trials[:2], values, strict=False):
                http.post(f"/api/v1/trials/{trial['id']}/tell", json={"value": value})

            browser.navigate(f"{server.url}/#/studies/{study}")
            browser.wait_for(STUDY_PAGE_READY)
            assert browser.evaluate(f"{CARD}.hidden") is False
            assert browser.evaluate(CELLS) == [
                "value",
                "2",
                "0.375",
                "0.1768",
                "0.25",
                "0.375",
                "0.5",
            ]
            meta = browser.evaluate("document.querySelector('[data-meta]').textContent")
            assert "one design, no proposer" in meta and "proposer qei" not in meta

            http.post(f"/api/v1/trials/{trials[2]['id']}/tell", json={"value": values[2]})
            mean, std = statistics.fmean(values), statistics.stdev(values)
            assert browser.wait_for(f"{CELLS}[1] === '3' && {CELLS}")[2:4] == [
                f"{mean:.4g}",
                f"{std:.4g}",
            ]

        browser.navigate(f"{server.url}/#/studies/{other}")
        browser.wait_for(f"{STUDY_PAGE_READY} && document.title.startsWith('stand-up')")
        assert browser.evaluate(f"{CARD}.hidden") is True
        assert "proposer qei" in browser.evaluate(
            "document.querySelector('[data-meta]').textContent"
        )
        assert browser.errors == []
    finally:
        server.stop()
