"""The dashboard in a real headless Chromium against a real ``adserver``.

The checks read the rendered page, not the HTML: canvas pixels and the counts the
charts drew, the table's rows, an image's decoded width, and the same document
following a study as trials are told. Robots in 3D and a 10,000-trial study have
files of their own (test_dashboard_robots_browser, test_dashboard_scale_browser).
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable

import httpx
import pytest

from adclient.testing.servers import ServerProcess, make_token
from tests.service.chromium import Chromium
from tests.service.dashboard_pages import (
    BLUE,
    COUNT_PIXELS,
    DISPLAY,
    MANAGED_BOX,
    ORANGE,
    PARAMS,
    STUDY_PAGE_READY,
    TABLE_NUMBERS,
    TABLE_STATES,
    lease,
    png,
    score,
    seed_mixed_study,
    tell,
    upload,
)

pytestmark = [pytest.mark.browser, pytest.mark.e2e, pytest.mark.xdist_group("browser")]


def test_study_page_draws_the_study_and_follows_it_live(
    live_server: ServerProcess, browser: Chromium
) -> None:
    with httpx.Client(base_url=live_server.url, timeout=30) as http:
        seeded = seed_mixed_study(http)
        other = {
            key: value for key, value in MANAGED_BOX.items() if key not in ("task", "max_trials")
        }
        other.update(name="another-study", direction="minimize")
        other_id = http.post("/api/v1/studies", json=other).raise_for_status().json()["id"]
        other_values = [3.0, 1.0, 2.0, 0.5, 4.0]
        asked = http.post(f"/api/v1/studies/{other_id}/ask", json={"count": 5}).json()["trials"]
        for trial, value in zip(asked, other_values, strict=True):
            tell(http, trial["id"], value=value)
        study_id = seeded["study"]["id"]
        best, values = seeded["best"], seeded["values"]

        # The studies list, then into the study by its link: hash routing, no reload.
        browser.navigate(f"{live_server.url}/")
        names = browser.wait_for(
            "[...document.querySelectorAll('table.studies tbody tr')]"
            ".map(row => row.cells[0].querySelector('a').textContent)"
        )
        assert sorted(names) == ["another-study", "dashboard-box"]
        row_text = browser.evaluate(
            "[...document.querySelectorAll('table.studies tbody tr')]"
            ".find(row => row.textContent.includes('dashboard-box')).textContent"
        )
        assert "8 complete · 3 running · 0 queued · 2 failed of 40" in " ".join(row_text.split())
        assert "0.5" in browser.evaluate(
            "[...document.querySelectorAll('table.studies tbody tr')]"
            ".find(row => row.textContent.includes('another-study')).cells[3].textContent"
        )
        browser.evaluate("window.sameDocument = true")
        browser.evaluate(
            f"document.querySelector('table.studies a[href=\"#/studies/{study_id}\"]').click()"
        )
        browser.wait_for(STUDY_PAGE_READY)
        assert (
            browser.evaluate("document.querySelector('[data-name]').textContent") == "dashboard-box"
        )

        # Progress and counts.
        counts = browser.evaluate("document.querySelector('[data-counts]').textContent")
        for text in ("8 complete", "3 running", "0 queued", "2 failed", "13 asked of 40"):
            assert text in counts
        segments = browser.evaluate(
            "[...document.querySelectorAll('.study [data-progress] .segment')]"
            ".map(s => [s.classList[1], parseFloat(s.style.width)])"
        )
        assert dict(segments) == pytest.approx({"complete": 20, "failed": 5, "running": 7.5})

        # The history chart drew every complete trial and the best-so-far curve.
        history = "[data-history]"
        assert browser.evaluate(f"document.querySelector('{history}').dataset.points") == "8"
        assert browser.evaluate(f"document.querySelector('{history}').dataset.failed") == "2"
        assert float(
            browser.evaluate(f"document.querySelector('{history}').dataset.bestSoFar")
        ) == pytest.approx(max(values.values()))
        assert browser.evaluate(f"{COUNT_PIXELS}('{history}', {ORANGE}, 40)") > 50
        assert browser.evaluate(f"{COUNT_PIXELS}('{history}', {BLUE}, 40)") > 8 * 4
        # Parallel coordinates: one line per complete trial.
        assert browser.evaluate("document.querySelector('[data-parallel]').dataset.lines") == "8"
        assert browser.evaluate(f"{COUNT_PIXELS}('[data-parallel]', null, 0)") > 1000

        # Slices: one plot per param, each with a point per complete trial; the other
        # views hidden.
        browser.evaluate("document.querySelector('button[data-tab=\"slices\"]').click()")
        captions = browser.evaluate(
            "[...document.querySelectorAll('[data-slices] figcaption')].map(c => c.textContent)"
        )
        assert sorted(captions) == sorted(PARAMS)
        for k in range(len(PARAMS)):
            selector = f"[data-slices] figure:nth-child({k + 1}) canvas"
            assert browser.evaluate(f"{COUNT_PIXELS}('{selector}', null, 0)") > 8 * 4
        assert browser.evaluate(f"{DISPLAY}('[data-parallel]')") == "none"
        browser.evaluate("document.querySelector('button[data-tab=\"correlation\"]').click()")
        assert len(browser.evaluate("[...document.querySelectorAll('.corr-row')]")) == 3
        assert browser.evaluate(f"{DISPLAY}('[data-slices]')") == "none"
        browser.evaluate("document.querySelector('button[data-tab=\"parallel\"]').click()")
        assert browser.evaluate(f"{DISPLAY}('[data-parallel]')") == "block"

        # The table: every trial, newest first, with its state.
        assert browser.evaluate(TABLE_NUMBERS) == list(range(12, -1, -1))
        states = browser.evaluate(TABLE_STATES)
        assert sorted(states) == sorted(["complete"] * 8 + ["failed"] * 2 + ["running"] * 3)
        assert browser.evaluate("document.querySelector('[data-trials]').dataset.total") == "13"

        # The best design: its image decoded, its score and params, its URDF.
        assert browser.wait_for("document.querySelector('[data-best-image]').naturalWidth") == 64
        shown = float(browser.evaluate("document.querySelector('.best-value').textContent"))
        assert shown == pytest.approx(best["value"], rel=1e-3)
        assert shown == pytest.approx(max(values.values()), rel=1e-3)
        best_text = browser.evaluate("document.querySelector('[data-best]').textContent")
        assert f"#{best['number']}" in best_text and "x" in best_text
        urdf = browser.evaluate(
            "(async () => { const a = document.querySelector('[data-best] a[data-download]');"
            " const r = await fetch(a.href); return [a.getAttribute('href'), await r.text()]; })()"
        )
        assert urdf[0] == f"/api/v1/trials/{best['id']}/artifacts/robot.urdf"
        assert urdf[1].startswith("<robot")

        # Workers: who holds which lease, jobs done and failed, the tasks and learners
        # each named (none: any).
        workers = browser.evaluate(
            "[...document.querySelectorAll('table.workers tbody tr')]"
            ".map(row => [...row.cells].map(cell => cell.textContent.trim()))"
        )
        by_name = {row[0]: row for row in workers}
        assert set(by_name) == {"worker-1", "worker-2"}
        assert by_name["worker-1"][1] == f"trial #{seeded['held']['number']}"
        assert by_name["worker-2"][1] == "idle"
        for name in ("worker-1", "worker-2"):
            done, failed = str(seeded["done"][name]), str(seeded["failed"][name])
            assert by_name[name][3:] == [done, failed, "any", "any"]

        # A row opens its trial: image and files.
        browser.evaluate("document.querySelector('tr.is-best a[data-image]').click()")
        assert (
            browser.wait_for(
                "document.querySelector('[data-trial-dialog]').open"
                " && document.querySelector('[data-trial-image]')?.naturalWidth"
            )
            == 64
        )
        dialog = browser.evaluate("document.querySelector('[data-trial-dialog]').textContent")
        assert f"Trial #{best['number']}" in dialog and "robot.png" in dialog
        browser.evaluate("document.querySelector('[data-trial-dialog] [data-close]').click()")

        # Sorting happens on the server: by score, best first, then worst first.
        browser.evaluate("document.querySelector('th[data-sort=\"value\"]').click()")
        ranked = sorted(values, key=lambda number: -values[number])
        first_eight = f"{TABLE_NUMBERS}.slice(0, 8).join(',')"
        browser.wait_for(f"{first_eight} === '{','.join(map(str, ranked))}'")
        browser.evaluate("document.querySelector('th[data-sort=\"value\"]').click()")
        browser.wait_for(f"{first_eight} === '{','.join(map(str, ranked[::-1]))}'")
        # ... and by a param picked in the toolbar: ascending, then reversed.
        trials = http.get(f"/api/v1/studies/{study_id}/trials").raise_for_status().json()
        by_x = [t["number"] for t in sorted(trials, key=lambda t: t["params"]["x"])]
        picker = "document.querySelector('[data-sort-param]')"
        browser.wait_for(f"[...{picker}.options].some(option => option.value === 'x')")
        browser.evaluate(f"{picker}.value = 'x'; {picker}.dispatchEvent(new Event('change'))")
        every_number = f"{TABLE_NUMBERS}.join(',')"
        browser.wait_for(f"{every_number} === '{','.join(map(str, by_x))}'")
        browser.evaluate("document.querySelector('[data-sort-direction]').click()")
        browser.wait_for(f"{every_number} === '{','.join(map(str, by_x[::-1]))}'")
        browser.evaluate("document.querySelector('th[data-sort=\"value\"]').click()")
        browser.wait_for(f"{TABLE_NUMBERS}[0] === {best['number']}")
        assert browser.evaluate(f"{picker}.value") == ""

        # Live: a better trial is told; the same document shows it without a reload.
        held = seeded["held"]
        new_value = best["value"] + 10.0
        upload(http, held["trial_id"], "robot.png", png(80, 60), "image/png", "worker-1")
        tell(http, held["trial_id"], value=new_value, worker_id="worker-1")
        browser.wait_for(f"{TABLE_NUMBERS}[0] === {held['number']}")
        browser.wait_for(f"document.querySelector('{history}').dataset.points === '9'")
        browser.wait_for(
            f"Math.abs(parseFloat(document.querySelector('.best-value').textContent)"
            f" - {new_value}) < 1e-2"
        )
        assert "9 complete" in browser.evaluate(
            "document.querySelector('[data-counts]').textContent"
        )
        # The new best's own image replaces the old one.
        assert browser.wait_for("document.querySelector('[data-best-image]').naturalWidth") == 80
        workers_after = browser.wait_for(
            "(() => { const row = [...document.querySelectorAll('table.workers tbody tr')]"
            ".find(r => r.cells[0].textContent === 'worker-1');"
            " return row.cells[1].textContent === 'idle' && row.cells[3].textContent; })()"
        )
        assert workers_after == str(seeded["done"]["worker-1"] + 1)
        assert browser.evaluate("window.sameDocument") is True
        assert browser.evaluate("window.adMetrics.updates.length") >= 1

        # A minimising study: the best so far is the lowest score.
        browser.evaluate(f"location.hash = '#/studies/{other_id}'")
        browser.wait_for(
            f"{STUDY_PAGE_READY} && document.querySelector('[data-name]').textContent"
            " === 'another-study'"
        )
        assert browser.evaluate("window.sameDocument") is True
        assert float(
            browser.evaluate(f"document.querySelector('{history}').dataset.bestSoFar")
        ) == min(other_values)
        shown = browser.evaluate("document.querySelector('.best-value').textContent")
        assert float(shown) == min(other_values)
    assert browser.errors == []


# One server for the three (each looks at its own study): conftest's, on SQLite.
@pytest.mark.parametrize("shared_server", ["sqlite"], indirect=True)
def test_best_card_of_a_box_study_shows_its_score_link_and_params(
    shared_server: ServerProcess, browser: Chromium
) -> None:
    """An ask/tell box study has no image and no URDF: the card shows the best score, the
    trial's link and its params where a reader sees them, not a missing image. (They once
    went into the history canvas, whose data-best attribute the card's lookup found first;
    a test reading `[data-best]` from the document could not tell.)"""
    body = {key: value for key, value in MANAGED_BOX.items() if key not in ("task", "max_trials")}
    with httpx.Client(base_url=shared_server.url, timeout=30) as http:
        study = http.post("/api/v1/studies", json=dict(body, name="plain-box")).raise_for_status()
        study_id = study.json()["id"]
        asked = http.post(f"/api/v1/studies/{study_id}/ask", json={"count": 4}).json()["trials"]
        for trial in asked:
            tell(http, trial["id"], value=score(trial["params"]))
        best = http.get(f"/api/v1/studies/{study_id}/best").raise_for_status().json()

    browser.navigate(f"{shared_server.url}/#/studies/{study_id}")
    browser.wait_for(STUDY_PAGE_READY)
    card = "document.querySelector('[data-best-card]')"
    text = browser.evaluate(f"{card}.innerText")
    assert f"trial #{best['number']}" in text
    assert "No image" not in text and "No complete trial" not in text
    assert all(name in text for name in PARAMS)
    assert browser.evaluate(f"{card}.querySelector('.best-value').checkVisibility()") is True
    shown = float(browser.evaluate(f"{card}.querySelector('.best-value').textContent"))
    assert shown == pytest.approx(best["value"], rel=1e-3)
    assert browser.evaluate(f"{card}.querySelector('[data-best-figure]').hidden") is True
    assert browser.evaluate("document.querySelector('[data-history]').textContent") == ""
    browser.evaluate(f"{card}.querySelector('a[data-open-trial]').click()")
    browser.wait_for("document.querySelector('[data-trial-dialog]').open")
    dialog = browser.evaluate("document.querySelector('[data-trial-dialog]').textContent")
    assert f"Trial #{best['number']}" in dialog
    assert browser.evaluate("!!document.querySelector('[data-trial-dialog] .robot-view')") is False
    assert browser.errors == []


# The session's storage: test_ownership_e2e's cookie session test, on both databases.
@pytest.mark.parametrize("database", ["sqlite"])
def test_sign_in_keeps_the_token_out_of_urls_and_page_scripts(
    server_factory: Callable[..., ServerProcess], browser: Chromium
) -> None:
    server = server_factory(AD_AUTH="true")
    admin, reader = make_token(server, "admin"), make_token(server, "reader", name="rita")
    with httpx.Client(
        base_url=server.url, timeout=30, headers={"Authorization": f"Bearer {admin}"}
    ) as http:
        seeded = seed_mixed_study(http)
    study_id = seeded["study"]["id"]

    browser.navigate(f"{server.url}/#/studies/{study_id}")
    browser.wait_for("!document.querySelector('[data-auth]').hidden")
    assert "requires a token" in browser.evaluate(
        "document.querySelector('[data-auth]').textContent"
    )
    # Type the token into the form and submit it, as a person does.
    browser.evaluate(
        f"(() => {{ const form = document.querySelector('[data-auth] form');"
        f" form.elements.token.value = {json.dumps(reader)}; form.requestSubmit(); }})()"
    )
    browser.wait_for(STUDY_PAGE_READY)
    assert browser.evaluate("document.querySelector('[data-auth]').hidden") is True
    assert "rita" in browser.evaluate("document.querySelector('[data-signed-in]').textContent")
    assert "by admin" in browser.evaluate("document.querySelector('[data-meta]').textContent")
    assert browser.wait_for("document.querySelector('[data-best-image]').naturalWidth") == 64
    assert browser.evaluate("document.querySelector('[data-trials]').dataset.total") == "13"

    # The token is nowhere a page script or a log could find it.
    assert browser.evaluate("document.querySelector('[data-auth] input').value") == ""
    assert browser.evaluate("document.cookie") == ""  # the session cookie is HttpOnly
    storage = browser.evaluate(
        "JSON.stringify([{...localStorage}, {...sessionStorage}, location.href])"
    )
    assert reader not in storage and "ad_token" not in storage
    assert browser.requested, "no request was recorded"
    assert not [url for url in browser.requested if reader in url or "token=" in url]
    assert all(url.startswith(server.url) or url.startswith("data:") for url in browser.requested)

    # Signing out ends the session on the server: the page asks again.
    browser.evaluate("document.querySelector('[data-sign-out]').click()")
    browser.wait_for("!document.querySelector('[data-auth]').hidden")
    refused = browser.evaluate("fetch('/api/v1/studies').then(r => r.status)")
    assert refused == 401
    assert all("401" in error for error in browser.errors)  # only the refused visits


# Headers, not storage: test_ownership_e2e's artifacts-served-inert test, on both databases.
@pytest.mark.parametrize("database", ["sqlite"])
def test_scripted_artifacts_run_no_script(
    server_factory: Callable[..., ServerProcess], browser: Chromium
) -> None:
    """A worker uploads script as an SVG named robot.png and as HTML: opened in the
    dashboard or in a tab of their own, neither runs on the dashboard's origin."""
    server = server_factory()
    marker = "localStorage.setItem('pwned', document.domain)"
    svg = (
        '<svg xmlns="http://www.w3.org/2000/svg" width="64" height="48">'
        f"<script>{marker}</script><rect width='64' height='48'/></svg>"
    ).encode()
    html = f"<html><body><script>{marker}</script></body></html>".encode()
    with httpx.Client(base_url=server.url, timeout=30) as http:
        study = http.post("/api/v1/studies", json=MANAGED_BOX).raise_for_status().json()
        job = lease(http, "worker-1")
        upload(http, job["trial_id"], "robot.png", svg, "image/svg+xml", "worker-1")
        upload(http, job["trial_id"], "page.html", html, "text/html", "worker-1")
        tell(http, job["trial_id"], value=1.0, worker_id="worker-1")
    base = f"{server.url}/api/v1/trials/{job['trial_id']}/artifacts"

    browser.navigate(f"{server.url}/#/studies/{study['id']}")
    browser.wait_for(STUDY_PAGE_READY)
    # The marker mechanism works on this origin (so its absence below means something).
    browser.evaluate("localStorage.setItem('probe', '1')")
    assert browser.evaluate("localStorage.getItem('probe')") == "1"
    browser.evaluate(f"document.querySelector('[data-open-trial=\"{job['trial_id']}\"]')?.click()")
    for url in (f"{base}/robot.png", f"{base}/page.html"):
        browser.navigate(url)  # "open image in new tab": a download, never a page
        time.sleep(1.0)
    browser.navigate(f"{server.url}/#/studies/{study['id']}")
    browser.wait_for(STUDY_PAGE_READY)
    assert browser.evaluate("localStorage.getItem('pwned')") is None
    assert browser.evaluate("localStorage.getItem('probe')") == "1"
    # And the dashboard itself never wrapped an artifact in a blob or data URL.
    assert not [url for url in browser.requested if url.startswith(("blob:", "data:image/svg"))]


# Pruned counts, lists and columns: test_pruning_e2e's pruned-tells test, on both databases.
# One server for the three (each looks at its own study): conftest's, on SQLite.
@pytest.mark.parametrize("shared_server", ["sqlite"], indirect=True)
def test_pruned_trials_in_the_progress_bar_counts_and_filter(
    shared_server: ServerProcess, browser: Chromium
) -> None:
    with httpx.Client(base_url=shared_server.url, timeout=30) as http:
        body = {**MANAGED_BOX, "name": "pruned-box", "max_trials": 10}
        body["pruner"] = {"name": "median", "options": {"n_startup_trials": 1}}
        study_id = http.post("/api/v1/studies", json=body).raise_for_status().json()["id"]
        asked = http.post(f"/api/v1/studies/{study_id}/ask", json={"count": 4}).json()["trials"]
        tell(http, asked[0]["id"], value=1.0)
        for trial in asked[1:3]:
            http.post(f"/api/v1/trials/{trial['id']}/report", json={"step": 5, "value": 0.25})
            tell(http, trial["id"], state="pruned")
        browser.navigate(f"{shared_server.url}/#/studies/{study_id}")
        browser.wait_for(STUDY_PAGE_READY)
        counts = browser.evaluate("document.querySelector('[data-counts]').textContent")
        assert "2 pruned" in counts and "1 complete" in counts
        segments = browser.evaluate(
            "[...document.querySelectorAll('.study [data-progress] .segment')]"
            ".map(s => [s.classList[1], parseFloat(s.style.width)])"
        )
        assert dict(segments) == pytest.approx({"complete": 10, "pruned": 20, "running": 10})
        options = browser.evaluate(
            "[...document.querySelectorAll('[data-filter] option')].map(o => o.textContent)"
        )
        assert "pruned" in options


# The typed columns on PostgreSQL: test_dashboard_reads (int and categorical columns).
# One server for the three (each looks at its own study): conftest's, on SQLite.
@pytest.mark.parametrize("shared_server", ["sqlite"], indirect=True)
def test_int_and_categorical_params_are_charted_with_their_choices_as_ticks(
    shared_server: ServerProcess, browser: Chromium
) -> None:
    """A categorical param is an axis of the parallel coordinates and a slice plot whose
    ticks are its choices (in the space's order), an int param an axis of its own; the
    trial table shows each param as the trial has it (an int without a decimal point)."""
    choices = ["relu", "tanh", "gelu"]
    space = {
        "type": "box",
        "params": [
            {"name": "width", "type": "int", "low": 1, "high": 64, "log": True},
            {"name": "activation", "type": "categorical", "choices": choices},
        ],
    }
    with httpx.Client(base_url=shared_server.url, timeout=30) as http:
        body = {"name": "typed", "space": space, "proposer": {"name": "random", "seed": 4}}
        study_id = http.post("/api/v1/studies", json=body).raise_for_status().json()["id"]
        trials = http.post(f"/api/v1/studies/{study_id}/ask", json={"count": 12}).json()["trials"]
        for trial in trials:
            value = trial["params"]["width"] + 10 * choices.index(trial["params"]["activation"])
            tell(http, trial["id"], value=value)
        series = http.get(f"/api/v1/dashboard/studies/{study_id}/series").json()
    assert series["params"]["activation"] == [t["params"]["activation"] for t in trials]
    assert series["params"]["width"] == [t["params"]["width"] for t in trials]
    assert {t["params"]["activation"] for t in trials} == set(choices)  # all three vary

    browser.navigate(f"{shared_server.url}/#/studies/{study_id}")
    browser.wait_for(STUDY_PAGE_READY)
    parallel = "document.querySelector('[data-parallel]')"
    assert browser.evaluate(f"{parallel}.dataset.lines") == "12"
    assert browser.evaluate(f"{parallel}.dataset.drawn") == "12"
    assert json.loads(browser.evaluate(f"{parallel}.dataset.ticks")) == {"activation": choices}
    assert browser.evaluate(f"{COUNT_PIXELS}('[data-parallel]', null, 0)") > 1000
    browser.evaluate("document.querySelector('button[data-tab=\"slices\"]').click()")
    captions = browser.evaluate(
        "[...document.querySelectorAll('[data-slices] figcaption')].map(c => c.textContent)"
    )
    assert sorted(captions) == ["activation", "width"]
    ticks = {
        name: json.loads(
            browser.evaluate(
                f"document.querySelector('[data-slices] figure:nth-child({k + 1}) canvas')"
                ".dataset.ticks"
            )
        )
        for k, name in enumerate(captions)
    }
    assert ticks == {"activation": choices, "width": None}
    rows = browser.evaluate(
        "[...document.querySelectorAll('[data-trials] tbody td.params')].map(c => c.textContent)"
    )
    assert rows and all("width=" in row and "." not in row.split("width=")[1] for row in rows)
    assert browser.errors == []


@pytest.mark.parametrize("database", ["sqlite"])  # it reads nothing from the database
def test_the_page_keeps_its_width_when_it_grows_a_scrollbar(
    live_server: ServerProcess, browser: Chromium
) -> None:
    """The page always has its scrollbar (dashboard.css, ``overflow-y: scroll`` on the
    root): a page that grew one used to lay out 15 px narrower, so every chart drawn
    before redrew at another size a moment later, its points moving under the mouse.
    The studies list, its content set aside so the page is short whatever studies the
    server has; a tall block then makes it scroll."""
    browser.navigate(f"{live_server.url}/")
    browser.wait_for(
        "document.querySelector('table.studies') !== null"
        " || document.body.textContent.includes('No studies yet')"
    )
    browser.evaluate("[...document.body.children].forEach((child) => { child.hidden = true; })")
    width = "document.documentElement.clientWidth"
    tall = "document.documentElement.scrollHeight > innerHeight"
    assert browser.evaluate(tall) is False
    before = browser.evaluate(width)
    browser.evaluate(
        "(() => { const block = document.createElement('div');"
        " block.id = 'tall'; block.style.height = '5000px';"
        " document.body.appendChild(block); })()"
    )
    assert browser.wait_for(tall) is True
    assert browser.evaluate(width) == before
    assert browser.errors == []
