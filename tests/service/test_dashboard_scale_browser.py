"""A 10,000-trial study on the dashboard, in a real headless Chromium against a real
``adserver``: it renders, follows a tell and an ask, and pages and sorts on the server.
Its render and update times go to the log (no timing asserts; goals live in bench/)."""

from __future__ import annotations

import json
import time
from collections.abc import Callable

import httpx
import numpy as np
import pytest

from adclient.schemas import TellRequest
from adclient.testing.servers import ServerProcess
from adservice.db import Database
from adservice.principals import OPEN_ADMIN
from adservice.repository import tell as tell_repo
from adservice.repository import trials as trial_repo
from tests.service.chromium import Chromium
from tests.service.dashboard_pages import (
    MANAGED_BOX,
    PARAMS,
    STUDY_PAGE_READY,
    TABLE_NUMBERS,
    TABLE_STATES,
    score,
    tell,
)

pytestmark = [pytest.mark.browser, pytest.mark.e2e, pytest.mark.xdist_group("browser")]


def seed_many(database_url: str, study_id: int, count: int, open_count: int) -> list[int]:
    """``count`` trials straight into the database (fast), all told but the last
    ``open_count``; every 50th told one failed. Returns the ids of the open ones."""
    rng = np.random.default_rng(5)
    vectors = rng.random((count, len(PARAMS)))
    params = [dict(zip(PARAMS, map(float, vector), strict=True)) for vector in vectors]
    db = Database(database_url)
    try:
        with db.write() as session:
            first = trial_repo.reserve_numbers(session, study_id=study_id, count=count)
            trials = trial_repo.insert_trials(
                session,
                study_id=study_id,
                first_number=first,
                vectors=vectors.tolist(),
                params=params,
                infos=[{}] * count,
            )
            for k, trial in enumerate(trials[: count - open_count]):
                body = (
                    TellRequest(state="failed", message="seeded failure")
                    if k % 50 == 7
                    else TellRequest(value=score(trial.params))
                )
                tell_repo.tell_trial(session, trial_id=trial.id, body=body, caller=OPEN_ADMIN)
    finally:
        db.dispose()
    return [trial.id for trial in trials[count - open_count :]]


@pytest.mark.slow
@pytest.mark.parametrize("database", ["sqlite"])
def test_ten_thousand_trials_render_and_update(
    database: str,
    server_factory: Callable[..., ServerProcess],
    browser: Chromium,
    record_property: Callable[[str, object], None],
    capsys: pytest.CaptureFixture[str],
) -> None:
    server = server_factory()
    count, open_count = 10_000, 20
    with httpx.Client(base_url=server.url, timeout=60) as http:
        body = {
            key: value for key, value in MANAGED_BOX.items() if key not in ("task", "max_trials")
        }
        study = http.post("/api/v1/studies", json=dict(body, name="ten-thousand")).json()
        open_ids = seed_many(server.database_url, study["id"], count, open_count)
        n_failed = len([k for k in range(count - open_count) if k % 50 == 7])
        n_complete = count - open_count - n_failed

        started = time.monotonic()
        browser.navigate(f"{server.url}/#/studies/{study['id']}")
        browser.wait_for(STUDY_PAGE_READY, timeout=120)
        ready_s = time.monotonic() - started
        first_render = browser.evaluate("window.adMetrics.firstRenderMs")
        page_render = browser.evaluate("window.adMetrics.renders[0]")
        assert browser.evaluate("document.querySelector('[data-history]').dataset.points") == str(
            n_complete
        )
        assert browser.evaluate("document.querySelector('[data-parallel]').dataset.lines") == str(
            n_complete
        )
        assert browser.evaluate("document.querySelector('[data-trials]').dataset.total") == str(
            count
        )
        assert browser.evaluate(TABLE_NUMBERS)[:3] == [count - 1, count - 2, count - 3]

        # One open trial is told and a new one asked: the page follows both.
        updates_before = browser.evaluate("window.adMetrics.updates.length")
        told_at = time.monotonic()
        tell(http, open_ids[-1], value=100.0)
        browser.wait_for(f"{TABLE_STATES}[0] === 'complete'", timeout=60)
        tell_visible_s = time.monotonic() - told_at
        browser.wait_for(f"window.adMetrics.updates.length > {updates_before}")
        tell_update = browser.evaluate("window.adMetrics.updates.at(-1)")
        assert browser.evaluate("document.querySelector('[data-history]').dataset.points") == str(
            n_complete + 1
        )
        updates_before = browser.evaluate("window.adMetrics.updates.length")
        http.post(f"/api/v1/studies/{study['id']}/ask", json={"count": 1}).raise_for_status()
        browser.wait_for(f"{TABLE_NUMBERS}[0] === {count}", timeout=60)
        browser.wait_for(f"window.adMetrics.updates.length > {updates_before}")
        ask_update = browser.evaluate("window.adMetrics.updates.at(-1)")

        # Paging and sorting go to the server: time them as a user would see them.
        started = time.monotonic()
        browser.evaluate("document.querySelector('[data-page=\"last\"]').click()")
        browser.wait_for(f"{TABLE_NUMBERS}.includes(0)")
        last_page_s = time.monotonic() - started
        started = time.monotonic()
        browser.evaluate("document.querySelector('th[data-sort=\"value\"]').click()")
        browser.wait_for(f"{TABLE_NUMBERS}[0] === {count - 1}")  # the 100.0 told above
        sort_s = time.monotonic() - started
    assert browser.errors == []

    timings = {
        "first_render_ms_since_navigation": round(first_render),
        "study_page_render_ms": round(page_render),
        "ready_seen_by_test_s": round(ready_s, 3),
        "update_after_tell_ms": round(tell_update["ms"]),
        "update_after_tell_fetch_ms": round(tell_update["fetchMs"]),
        "update_after_tell_render_ms": round(tell_update["renderMs"]),
        "update_after_ask_ms": round(ask_update["ms"]),
        "tell_to_visible_s_incl_2s_polling": round(tell_visible_s, 3),
        "table_last_page_s": round(last_page_s, 3),
        "table_sort_by_score_s": round(sort_s, 3),
    }
    for name, value in timings.items():
        record_property(name, value)
    with capsys.disabled():
        print(f"\ndashboard with {count} trials: {json.dumps(timings)}")
