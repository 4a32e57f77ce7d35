"""Issue 62's dashboard numbers, in a real headless Chromium against a real ``adserver``:
axis ticks rounded to the axis' step (a score axis labelled ``-2.78e-17`` for 0),
integers shown exactly (``train_steps`` 12288, not 12290), and a log scale on the
history chart (scores from 1e-4 to 60 are flat on a linear axis). One server
(conftest's ``shared_server``) and one browser."""

from __future__ import annotations

from typing import Any

import httpx
import pytest

from adclient.testing.servers import ServerProcess
from tests.service.chromium import Chromium
from tests.service.dashboard_pages import STUDY_PAGE_READY

pytestmark = [
    pytest.mark.browser,
    pytest.mark.e2e,
    pytest.mark.xdist_group("browser"),
    # what these pages read is the study's trials, asserted on PostgreSQL by
    # test_dashboard_reads; the numbers are the page's own
    pytest.mark.parametrize("shared_server", ["sqlite"], indirect=True),
]

CHARTS = "import(new URL('js/charts.js', document.baseURI).href)"
HISTORY = "document.querySelector('canvas[data-history]')"


@pytest.fixture(scope="module")
def server(shared_server: ServerProcess) -> ServerProcess:
    return shared_server


def study_of(http: httpx.Client, name: str, scores: list[float], **param: Any) -> int:
    """A box study with the given finished trials (added evaluations), ``param`` the
    one param's value in each."""
    ((key, value),) = param.items()
    space = {"type": "box", "params": [{"name": key, "type": "int", "low": 0, "high": 10**6}]}
    body = {"name": name, "direction": "minimize", "space": space}
    study = http.post("/api/v1/studies", json=body).raise_for_status().json()
    trials = [{"params": {key: value}, "value": score} for score in scores]
    http.post(f"/api/v1/studies/{study['id']}/trials", json=trials).raise_for_status()
    return int(study["id"])


def test_ticks_are_rounded_to_their_step_and_integers_shown_exactly(
    server: ServerProcess, browser: Chromium, http: httpx.Client
) -> None:
    browser.navigate(f"{server.url}/#/")
    browser.wait_for("document.readyState === 'complete'")
    ticks, texts, numbers = browser.evaluate(
        f"{CHARTS}.then(m => [m.niceTicks(-0.35, 0.25), m.niceTicks(-0.06, 0.05).map("
        "m.formatNumber), [12288, 200000, -3, 0.123456, 2.5e-5, 1234.5678].map(m.formatNumber)])"
    )
    assert ticks == [-0.3, -0.2, -0.1, 0, 0.1, 0.2]  # 0, not -2.78e-17
    assert texts == ["-0.06", "-0.04", "-0.02", "0", "0.02", "0.04"]  # not 6.94e-18
    assert numbers == ["12288", "200000", "-3", "0.1235", "2.50e-5", "1235"]
    steps = browser.evaluate(
        f"{CHARTS}.then(m => [m.niceTicks(-0.15, 0.15), m.niceTicks(0.1, 0.7), m.logTicks(-4, 2)])"
    )
    assert steps == [  # the low end is a tick where it is one (-0.15 was left out)
        [-0.15, -0.1, -0.05, 0, 0.05, 0.1, 0.15],
        [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7],
        [1e-4, 1e-3, 1e-2, 0.1, 1, 10, 100],
    ]

    study = study_of(http, "train-steps", [0.5], train_steps=12288)
    browser.navigate(f"{server.url}/#/studies/{study}")
    browser.wait_for(STUDY_PAGE_READY)
    cell = "document.querySelector('[data-best-params] td')?.textContent"
    assert browser.wait_for(cell) == "12288"
    assert browser.errors == []


def test_the_history_chart_has_a_log_scale_where_every_score_is_above_zero(
    server: ServerProcess, browser: Chromium, http: httpx.Client
) -> None:
    study = study_of(http, "decades", [60.0, 1.0, 1e-2, 1e-4], n=1)
    browser.navigate(f"{server.url}/#/studies/{study}")
    browser.wait_for(STUDY_PAGE_READY)
    browser.wait_for(f"{HISTORY}.dataset.points === '4'")
    gaps = f"[60, 1, 1e-2, 1e-4].map({HISTORY}.hit.y).map((y, k, ys) => k ? y - ys[k - 1] : 0)"
    assert browser.evaluate(f"{HISTORY}.dataset.scale") == "linear"
    linear = browser.evaluate(gaps)
    assert linear[3] < 0.01 * linear[1]  # 1e-2 to 1e-4: flat beside 60 to 1
    browser.evaluate("document.querySelector('[data-history-log]').click()")
    browser.wait_for(f"{HISTORY}.dataset.scale === 'log'")
    logged = browser.evaluate(gaps)
    # a decade is a decade: 1 to 1e-2 and 1e-2 to 1e-4 are the same height
    assert logged[2] == pytest.approx(logged[3]) and logged[3] > 0
    assert logged[1] == pytest.approx(logged[2] * 1.778 / 2, rel=1e-3)  # log10(60) = 1.778

    zero = study_of(http, "with-zero", [0.0, 1.0], n=1)
    browser.navigate(f"{server.url}/#/studies/{zero}")
    browser.wait_for(STUDY_PAGE_READY)
    browser.wait_for(f"{HISTORY}.dataset.points === '2'")
    assert browser.evaluate("document.querySelector('[data-history-log]').disabled") is True
    assert browser.evaluate(f"{HISTORY}.dataset.scale") == "linear"
    assert browser.errors == []
