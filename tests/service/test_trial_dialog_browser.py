"""A trial's dialog in a real headless Chromium against a real ``adserver``: it draws the
learning curve a real ``adworker`` wrote while training PPO (issue 60: the curve never
plotted), and a trial has an address of its own that opens its dialog, with closing,
back and forward keeping the address and the dialog in step (issue 62); its 3D view plays
the evaluation episode a real ``adworker`` recorded (``replay.json``, issue 60)."""

from __future__ import annotations

import json
from pathlib import Path

import httpx
import pytest

from adclient import Client
from adclient.testing.servers import SDK_HEADERS, ServerProcess
from tests.service.chromium import Chromium
from tests.service.dashboard_pages import (
    BLUE,
    CHANGED_PIXELS,
    COUNT_PIXELS,
    KEEP_PIXELS,
    STUDY_PAGE_READY,
)
from tests.workers.robots import fast_trained_trial, ppo_trained_trial

pytestmark = [
    pytest.mark.browser,
    pytest.mark.e2e,
    pytest.mark.xdist_group("browser"),
    # Artifacts and trials by number on PostgreSQL: test_ownership_e2e and
    # test_dashboard_api, on both.
    pytest.mark.parametrize("database", ["sqlite"]),
]

DIALOG = "document.querySelector('[data-trial-dialog]')"
CANVAS = "[data-trial-dialog] canvas[data-curve]"
EVALUATION_DOTS = [234, 88, 12]  # the dialog's evaluation episodes (charts.js)


def test_the_dialog_draws_the_curve_a_real_worker_wrote_training_ppo(
    live_server: ServerProcess, browser: Chromium, tmp_path: Path
) -> None:
    with Client(live_server.url) as client:
        trial = ppo_trained_trial(client, live_server, tmp_path, train_steps=128)
        curve = client.trial_curve(trial)
    assert len(curve.train) == 4 and len(curve.evaluation) == 3

    browser.navigate(f"{live_server.url}/#/studies/{trial.study_id}")
    browser.wait_for(STUDY_PAGE_READY)
    browser.evaluate(f"document.querySelector('tr[data-trial-id=\"{trial.id}\"]').click()")
    drawn = browser.wait_for(
        f"(() => {{ const c = document.querySelector({json.dumps(CANVAS)});"
        " return c && c.dataset.trainPoints !== undefined"
        " && [c.dataset.trainPoints, c.dataset.evaluationPoints]; })()"
    )
    assert drawn == ["4", "3"]  # every training episode and evaluation episode of the file
    line = browser.evaluate(f"{COUNT_PIXELS}({json.dumps(CANVAS)}, {BLUE}, 40)")
    dots = browser.evaluate(f"{COUNT_PIXELS}({json.dumps(CANVAS)}, {EVALUATION_DOTS}, 40)")
    assert line > 100, "no training line drawn"
    assert dots > 20, "no evaluation episodes marked"
    said = browser.evaluate("document.querySelector('[data-curve-score]').textContent")
    assert said == f"score: {curve.score}"
    assert "second-half mean" in said
    assert browser.errors == []


VIEW = "[data-trial-dialog] [data-robot-canvas]"


def view_state(browser: Chromium) -> dict:
    """What the dialog's 3D view and its player show now."""
    return browser.evaluate(
        f"(() => {{ const c = document.querySelector({json.dumps(VIEW)});"
        " const p = document.querySelector('[data-trial-dialog] [data-replay]');"
        " return {frame: c.dataset.frame, base: JSON.parse(c.dataset.base),"
        " scrub: p.querySelector('[data-replay-scrub]').value,"
        " playing: p.dataset.playing ?? null,"
        " time: p.querySelector('[data-replay-time]').textContent}; })()"
    )


def test_the_dialogs_3d_view_plays_the_episode_a_real_worker_recorded(
    live_server: ServerProcess, browser: Chromium, tmp_path: Path
) -> None:
    with Client(live_server.url) as client:
        trial = fast_trained_trial(client, live_server, tmp_path)
        replay = client.trial_replay(trial)
    frames = len(replay.frames)
    assert frames == 33  # the reset and stand-up's 32 control steps

    browser.navigate(f"{live_server.url}/{address(trial.study_id, trial.number)}")
    browser.wait_for(
        f"document.querySelector({json.dumps(VIEW)})?.dataset.replayFrames === '{frames}'",
        timeout=60,
    )
    start = view_state(browser)
    assert start["frame"] == "0" and start["scrub"] == "0"
    assert start["time"] == "0.00 / 3.20 s"
    assert start["base"]["position"] == pytest.approx(replay.position(0), abs=1e-4)
    browser.evaluate(f"{KEEP_PIXELS}({json.dumps(VIEW)}, 'start')")

    browser.evaluate("document.querySelector('[data-trial-dialog] [data-replay-play]').click()")
    # Played: the scrubber moves on while the pose changes, then stops at the last frame.
    moving = browser.wait_for(
        f"(() => {{ const s = document.querySelector({json.dumps(VIEW)}).dataset.frame;"
        f" return Number(s) > 0 && Number(s) < {frames - 1} && s; }})()",
        timeout=30,
    )
    assert 0 < int(moving) < frames - 1
    during = view_state(browser)
    assert during["playing"] == "true" and int(during["scrub"]) >= int(moving)
    browser.wait_for(
        "document.querySelector('[data-trial-dialog] [data-replay]').dataset.playing === 'false'",
        timeout=30,
    )
    end = view_state(browser)
    assert end["frame"] == end["scrub"] == str(frames - 1)
    # In the simulator's own pose: the root frame the worker recorded at the last step.
    assert end["base"]["position"] == pytest.approx(replay.position(frames - 1), abs=1e-4)
    assert end["base"]["orientation"] == pytest.approx(replay.orientation(frames - 1), abs=1e-3)
    assert end["base"]["position"] != pytest.approx(start["base"]["position"], abs=1e-3)
    joints = browser.evaluate(
        "Object.fromEntries([...document.querySelectorAll('[data-trial-dialog] input[data-joint]')]"
        ".map((i) => [i.dataset.joint, Number(i.value)]))"
    )
    # (a joint the simulator pushed a hair past its limit is shown at the limit)
    assert joints == pytest.approx(replay.joint_positions(frames - 1), abs=2e-3)
    assert browser.evaluate(f"{CHANGED_PIXELS}({json.dumps(VIEW)}, 'start')") > 200

    # Scrubbed back to a frame: that frame's pose, paused.
    browser.evaluate(
        "(() => { const s = document.querySelector('[data-trial-dialog] [data-replay-scrub]');"
        " s.value = '10';"
        " s.dispatchEvent(new Event('input')); })()"
    )
    scrubbed = view_state(browser)
    assert scrubbed["frame"] == "10" and scrubbed["playing"] == "false"
    assert scrubbed["base"]["position"] == pytest.approx(replay.position(10), abs=1e-4)
    # At 4x the rest of the episode plays on from there to the end.
    browser.evaluate(
        "(() => { const s = document.querySelector('[data-trial-dialog] [data-replay-speed]');"
        " s.value = '4';"
        " s.dispatchEvent(new Event('change'));"
        " document.querySelector('[data-trial-dialog] [data-replay-play]').click(); })()"
    )
    browser.wait_for(
        f"document.querySelector({json.dumps(VIEW)}).dataset.frame === '{frames - 1}'",
        timeout=30,
    )
    assert browser.errors == []


def address(study: int, number: int | None = None) -> str:
    return f"#/studies/{study}" + ("" if number is None else f"/trials/{number}")


def test_a_trials_address_opens_its_dialog_and_back_and_forward_follow_it(
    live_server: ServerProcess, browser: Chromium
) -> None:
    space = {"type": "box", "params": [{"name": "x", "low": 0, "high": 1}]}
    with httpx.Client(base_url=live_server.url, headers=SDK_HEADERS, timeout=30) as http:
        study = http.post("/api/v1/studies", json={"name": "linked", "space": space}).json()["id"]
        asked = http.post(f"/api/v1/studies/{study}/ask", json={"count": 3}).json()["trials"]
        for k, trial in enumerate(asked):
            http.post(f"/api/v1/trials/{trial['id']}/tell", json={"value": float(k)})
    ids = {trial["number"]: trial["id"] for trial in asked}

    def shows(number: int | None) -> None:
        """The dialog shows trial ``number`` (None: closed) and the address says so."""
        hash_is = f"location.hash === {json.dumps(address(study, number))}"
        if number is None:
            browser.wait_for(f"!{DIALOG}.open && {hash_is}")
            return
        title = f"Trial #{number} "
        browser.wait_for(
            f"{DIALOG}.open && {hash_is} && {DIALOG}.querySelector('h2')"
            f".textContent.startsWith({json.dumps(title)})"
        )

    # Opened as it is (a link, a bookmark, a screenshot's URL): the dialog is there.
    browser.navigate(f"{live_server.url}/{address(study, 1)}")
    browser.wait_for(STUDY_PAGE_READY)
    shows(1)
    browser.evaluate("window.studyPage = document.querySelector('.study')")
    browser.evaluate(f"{DIALOG}.querySelector('[data-close]').click()")
    shows(None)

    # Opened by a click on a row: its address is a new entry; back closes, forward opens.
    href = browser.evaluate(
        f"document.querySelector('tr[data-trial-id=\"{ids[2]}\"] td a').getAttribute('href')"
    )
    assert href == address(study, 2)
    browser.evaluate(f"document.querySelector('tr[data-trial-id=\"{ids[2]}\"]').click()")
    shows(2)
    browser.evaluate("history.back()")
    shows(None)
    browser.evaluate("history.forward()")
    shows(2)
    browser.evaluate(f"{DIALOG}.querySelector('[data-close]').click()")  # back to the study
    shows(None)
    browser.evaluate("history.forward()")
    shows(2)
    browser.evaluate(f"{DIALOG}.close()")  # as Esc closes it
    shows(None)

    # Another trial's address typed in: the same page opens its dialog; one not in the
    # study says so.
    browser.evaluate(f"location.hash = {json.dumps(address(study, 0))}")
    shows(0)
    browser.evaluate(f"location.hash = {json.dumps(address(study, 9))}")
    text = browser.wait_for(
        f"{DIALOG}.open && !!{DIALOG}.querySelector('[data-missing-trial]') && {DIALOG}.textContent"
    )
    assert "has no trial #9" in text
    browser.evaluate(f"{DIALOG}.querySelector('[data-close]').click()")
    browser.wait_for(f"!{DIALOG}.open && location.hash.startsWith('#/studies/{study}')")
    assert browser.evaluate("window.studyPage === document.querySelector('.study')") is True
    assert browser.errors == []
