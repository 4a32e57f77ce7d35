"""The best design card of the quadruped of bought parts (issue 40) in a real headless
Chromium against a real ``adserver``: its table lists the params the study searched (a
click away from the whole design), and its 3D view draws the robot where the simulator
starts it (``GET /api/v1/trials/{id}/spawn``), laid on its legs, not upright in its URDF
frame.

One server (conftest's ``shared_server``, SQLite: nothing here depends on the database)
and one browser serve the module (the Pareto tests' fixtures).
"""

from __future__ import annotations

import json
from typing import Any

import httpx
import pytest
import yaml

from adclient.testing.servers import ServerProcess
from tests.service.chromium import Chromium
from tests.service.dashboard_pages import EXAMPLES, STUDY_PAGE_READY, tell

pytestmark = [
    pytest.mark.browser,
    pytest.mark.e2e,
    pytest.mark.xdist_group("browser"),
    pytest.mark.parametrize("shared_server", ["sqlite"], indirect=True),
]

CARD = "[data-best-card]"
VIEW = f"{CARD} [data-robot-canvas]"
ROWS = f"[...document.querySelectorAll('{CARD} [data-best-params] th')].map(th => th.textContent)"
SLIDERS = (
    f"Object.fromEntries([...document.querySelectorAll('{CARD} input[data-joint]')]"
    ".map(input => [input.dataset.joint, Number(input.value)]))"
)


@pytest.fixture(scope="module")
def server(shared_server: ServerProcess) -> ServerProcess:
    """What the shared browser and client fixtures use."""
    return shared_server


@pytest.fixture(scope="module")
def quadruped(http: httpx.Client) -> dict[str, Any]:
    """The quadruped of examples/quadruped-budget.yaml (walk-forward), one trial told."""
    body = yaml.safe_load((EXAMPLES / "quadruped-budget.yaml").read_text())
    body.update(name="best-quadruped", proposer={"name": "random", "seed": 4})
    study = http.post("/api/v1/studies", json=body).raise_for_status().json()
    (trial,) = http.post(f"/api/v1/studies/{study['id']}/ask", json={}).json()["trials"]
    tell(http, trial["id"], value=0.25, metrics={"servos.mass": 0.6})
    return {"study": study, "trial": trial}


def open_best(browser: Chromium, server: ServerProcess, study_id: int) -> None:
    browser.navigate(f"{server.url}/#/studies/{study_id}")
    browser.wait_for(STUDY_PAGE_READY)
    browser.wait_for(f"document.querySelector('{VIEW}')?.dataset.ready === 'true'", timeout=60)


def test_the_best_design_shows_the_searched_params_and_all_of_them_a_click_away(
    server: ServerProcess, browser: Chromium, quadruped: dict[str, Any]
) -> None:
    study, trial = quadruped["study"], quadruped["trial"]
    searched = study["searched_params"]
    assert len(searched) == 6 and len(trial["params"]) > 100
    open_best(browser, server, study["id"])
    assert sorted(browser.evaluate(ROWS)) == sorted(searched)
    note = browser.evaluate(f"document.querySelector('{CARD} [data-best-note]').textContent")
    assert f"the 6 searched params; {len(trial['params']) - 6} more are fixed" in note

    show_all = f"document.querySelector('{CARD} [data-best-all]')"
    assert browser.evaluate(f"{show_all}.textContent") == f"Show all {len(trial['params'])}"
    browser.evaluate(f"{show_all}.click()")
    browser.wait_for(f"{ROWS}.length === {len(trial['params'])}")
    assert browser.evaluate(ROWS) == list(trial["params"])
    assert browser.evaluate(f"{show_all}.getAttribute('aria-pressed')") == "true"
    browser.evaluate(f"{show_all}.click()")
    browser.wait_for(f"{ROWS}.length === {len(searched)}")
    assert browser.errors == []


def test_the_3d_view_draws_the_robot_where_the_simulator_starts_it(
    server: ServerProcess, browser: Chromium, http: httpx.Client, quadruped: dict[str, Any]
) -> None:
    """The root frame as drawn (position, orientation) and the joint sliders are the
    spawn pose the server computes as the worker does (tests/workers/test_spawn_e2e.py
    holds the worker to it): for the quadruped, its torso lies along +x off the origin,
    not upright at it. A slider moved, Reset puts the joints back there; the trial's
    dialog draws it the same way."""
    trial = quadruped["trial"]
    spawn = http.get(f"/api/v1/trials/{trial['id']}/spawn").raise_for_status().json()
    assert spawn["fixed_base"] is False and spawn["position"][2] > 0.05
    assert spawn["orientation"] != pytest.approx([0, 0, 0, 1], abs=0.1)
    open_best(browser, server, quadruped["study"]["id"])

    def drawn(canvas: str) -> dict[str, Any]:
        return dict(
            json.loads(browser.evaluate(f"document.querySelector('{canvas}').dataset.base"))
        )

    base = drawn(VIEW)
    assert base["position"] == pytest.approx(spawn["position"], abs=1e-9)
    assert base["orientation"] == pytest.approx(spawn["orientation"], abs=1e-9)
    # what is drawn lies along x, its torso and legs in one line, low over the ground
    dx, _, dz = json.loads(browser.evaluate(f"document.querySelector('{VIEW}').dataset.extent"))
    assert dx > 3 * dz, (dx, dz)
    assert browser.evaluate(SLIDERS) == pytest.approx(spawn["joints"], abs=1e-12)
    assert len(spawn["joints"]) == 8

    slider = f"document.querySelector('{CARD} input[data-joint]')"
    browser.evaluate(
        f"{slider}.value = {slider}.max;"
        f" {slider}.dispatchEvent(new Event('input', {{ bubbles: true }}))"
    )
    assert browser.evaluate(SLIDERS) != pytest.approx(spawn["joints"], abs=1e-6)
    browser.evaluate(f"document.querySelector('{CARD} [data-robot-reset]').click()")
    assert browser.evaluate(SLIDERS) == pytest.approx(spawn["joints"], abs=1e-12)

    browser.evaluate(f"document.querySelector('{CARD} [data-open-trial]').click()")
    in_dialog = "[data-trial-dialog] [data-robot-canvas]"
    browser.wait_for(f"document.querySelector('{in_dialog}')?.dataset.ready === 'true'", timeout=60)
    assert drawn(in_dialog)["position"] == pytest.approx(spawn["position"], abs=1e-9)
    browser.evaluate("document.querySelector('[data-trial-dialog] [data-close]').click()")
    assert browser.errors == []
