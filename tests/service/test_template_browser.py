"""The dashboard's 3D view of issue 28's robots in a real Chromium: a template study's
trial drawn from its expanded xacro (the header says it is a template), and a design
whose joints are continuous, prismatic and fixed, with capsule links: a slider for each
driven joint in its unit, none for the fixed one."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import httpx
import pytest
import yaml

from adclient.testing.servers import ServerProcess
from tests.service.chromium import Chromium
from tests.service.dashboard_pages import ROBOT_PIXELS, STUDY_PAGE_READY, tell

# The group: the test process that runs the other browser tests runs it, on its Chromium.
pytestmark = [pytest.mark.browser, pytest.mark.e2e, pytest.mark.xdist_group("browser")]

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def kinds_study() -> dict[str, Any]:
    body = yaml.safe_load((EXAMPLES / "joint-kinds.yaml").read_text())
    body.pop("task")
    return dict(body)


def template_study() -> dict[str, Any]:
    body = yaml.safe_load((EXAMPLES / "template-arm.yaml").read_text())
    body["space"]["template"] = (EXAMPLES / "templates" / "arm.urdf.xacro").read_text()
    body.pop("task")
    return dict(body, proposer={"name": "random", "seed": 2})


def show_best(http: httpx.Client, browser: Chromium, url: str, body: dict[str, Any]) -> str:
    """Create the study, tell one trial, open its page: the best card's view selector."""
    study_id = http.post("/api/v1/studies", json=body).raise_for_status().json()["id"]
    (trial,) = http.post(f"/api/v1/studies/{study_id}/ask", json={"count": 1}).json()["trials"]
    tell(http, trial["id"], value=1.0)
    browser.navigate(f"{url}/#/studies/{study_id}")
    browser.wait_for(STUDY_PAGE_READY)
    view = "[data-best-card] [data-robot-canvas]"
    browser.wait_for(f"document.querySelector('{view}')?.dataset.ready === 'true'", timeout=60)
    card_url = browser.evaluate(
        "document.querySelector('[data-best-card] .robot-view').dataset.url"
    )
    assert card_url == f"/api/v1/trials/{trial['id']}/urdf"
    return view


@pytest.mark.parametrize("database", ["sqlite"])
def test_template_and_joint_kind_robots_in_3d(
    live_server: ServerProcess, browser: Chromium
) -> None:
    with httpx.Client(base_url=live_server.url, timeout=30) as http:
        view = show_best(http, browser, live_server.url, template_study())
        assert "robot template, 3 params" in browser.evaluate(
            "document.querySelector('[data-meta]').textContent"
        )
        assert browser.evaluate(f"document.querySelector('{view}').dataset.links") == "4"
        assert browser.evaluate(f"document.querySelector('{view}').dataset.joints") == "2"
        assert browser.evaluate(f"{ROBOT_PIXELS}('{view}')") > 500

        view = show_best(http, browser, live_server.url, kinds_study())
        assert browser.evaluate(f"document.querySelector('{view}').dataset.links") == "4"
        assert browser.evaluate(f"document.querySelector('{view}').dataset.joints") == "2"
        units = browser.evaluate(
            "[...document.querySelectorAll('[data-best-card] input[data-joint]')]"
            ".map(input => [input.dataset.joint, input.dataset.unit, +input.min, +input.max])"
        )
        assert units == [
            [
                "body_wheel",
                "rad",
                pytest.approx(-3.14159, abs=1e-4),
                pytest.approx(3.14159, abs=1e-4),
            ],
            ["body_lift", "m", 0.0, 0.2],
        ]
        assert browser.evaluate(f"{ROBOT_PIXELS}('{view}')") > 500
    assert all(url.startswith(live_server.url) for url in browser.requested)
    assert browser.errors == []
