"""Robots in 3D on the dashboard, in a real headless Chromium against a real
``adserver``: the best card's and the trial dialog's views, and a URDF that names
files elsewhere, which the page never fetches."""

from __future__ import annotations

import httpx
import pytest
import yaml

from adclient.testing.servers import ServerProcess
from tests.service.chromium import Chromium
from tests.service.dashboard_pages import (
    CHANGED_PIXELS,
    EXAMPLES,
    KEEP_PIXELS,
    MANAGED_BOX,
    ROBOT_PIXELS,
    STUDY_PAGE_READY,
    tell,
)

pytestmark = [pytest.mark.browser, pytest.mark.e2e, pytest.mark.xdist_group("browser")]


def drag(browser: Chromium, selector: str, dx: float, dy: float) -> None:
    """A left-button drag across an element, as a mouse makes it (real pointer events)."""
    x, y = browser.evaluate(
        f"(() => {{ const box = document.querySelector('{selector}').getBoundingClientRect();"
        " return [box.x + box.width / 2, box.y + box.height / 2]; })()"
    )
    mouse = {"button": "left", "clickCount": 1}
    browser.send("Input.dispatchMouseEvent", type="mousePressed", x=x, y=y, buttons=1, **mouse)
    for step in range(1, 6):
        at = {"x": x + dx * step / 5, "y": y + dy * step / 5}
        browser.send("Input.dispatchMouseEvent", type="mouseMoved", buttons=1, **at, **mouse)
    end = {"x": x + dx, "y": y + dy}
    browser.send("Input.dispatchMouseEvent", type="mouseReleased", buttons=0, **end, **mouse)


@pytest.mark.parametrize("database", ["sqlite"])
def test_robots_in_3d_in_the_best_card_and_the_trial_dialog(
    live_server: ServerProcess, browser: Chromium
) -> None:
    """A design study's URDFs drawn with the vendored three.js in the best card and in a
    trial's dialog (any trial: this one still runs). The WebGL canvas shows the links; a
    joint slider bends them, a drag turns the view, the wheel zooms, Reset puts it back; a
    new best replaces the card's robot; a closed dialog gives its GPU context back; and
    nothing is fetched from another origin."""
    body = yaml.safe_load((EXAMPLES / "stand-up.yaml").read_text())
    body.pop("task")
    body.update(name="robots-3d", proposer={"name": "random", "seed": 1})
    with httpx.Client(base_url=live_server.url, timeout=30) as http:
        study_id = http.post("/api/v1/studies", json=body).raise_for_status().json()["id"]
        asked = http.post(f"/api/v1/studies/{study_id}/ask", json={"count": 3}).json()["trials"]
        best, other, running = asked
        tell(http, best["id"], value=2.0)
        tell(http, other["id"], value=1.0)

        browser.navigate(f"{live_server.url}/#/studies/{study_id}")
        browser.wait_for(STUDY_PAGE_READY)
        card = "[data-best-card]"
        view = f"{card} [data-robot-canvas]"
        browser.wait_for(f"document.querySelector('{view}')?.dataset.ready === 'true'", timeout=60)
        model = f"document.querySelector('{card} .robot-view')"
        assert browser.evaluate(f"{model}.dataset.url") == f"/api/v1/trials/{best['id']}/urdf"
        assert browser.evaluate(f"document.querySelector('{view}').dataset.links") == "3"
        assert browser.evaluate(f"document.querySelector('{view}').dataset.joints") == "2"
        drawn = browser.evaluate(f"{ROBOT_PIXELS}('{view}')")
        assert drawn > 500, "the robot's links are not on the canvas"
        browser.evaluate(f"{KEEP_PIXELS}('{view}', 'first')")

        # A joint slider bends the robot; its value is shown.
        slider = f"document.querySelector('{card} input[data-joint]')"
        browser.evaluate(
            f"{slider}.value = {slider}.max;"
            f" {slider}.dispatchEvent(new Event('input', {{ bubbles: true }}))"
        )
        assert browser.evaluate(f"{CHANGED_PIXELS}('{view}', 'first')") > 200
        assert browser.evaluate(f"{slider}.nextElementSibling.textContent") == "1.571 rad"
        # A drag turns the view; the wheel zooms in (the robot fills more of it).
        browser.evaluate(f"{KEEP_PIXELS}('{view}', 'bent')")
        drag(browser, view, 120, 30)
        assert browser.evaluate(f"{CHANGED_PIXELS}('{view}', 'bent')") > 500
        before_zoom = browser.evaluate(f"{ROBOT_PIXELS}('{view}')")
        x, y = browser.evaluate(
            f"(() => {{ const box = document.querySelector('{view}').getBoundingClientRect();"
            " return [box.x + box.width / 2, box.y + box.height / 2]; })()"
        )
        browser.send("Input.dispatchMouseEvent", type="mouseWheel", x=x, y=y, deltaX=0, deltaY=-400)
        assert browser.evaluate(f"{ROBOT_PIXELS}('{view}')") > 1.3 * before_zoom
        # Reset: joints at zero, the camera on the whole robot: the first picture again.
        browser.evaluate(f"document.querySelector('{card} [data-robot-reset]').click()")
        assert browser.evaluate(f"{CHANGED_PIXELS}('{view}', 'first')") < 20

        # A trial still running, opened from the table: its own robot in the dialog.
        browser.evaluate(f"document.querySelector('tr[data-trial-id=\"{running['id']}\"]').click()")
        in_dialog = "[data-trial-dialog] [data-robot-canvas]"
        browser.wait_for(
            f"document.querySelector('{in_dialog}')?.dataset.ready === 'true'", timeout=60
        )
        assert (
            browser.evaluate(
                "document.querySelector('[data-trial-dialog] .robot-view').dataset.url"
            )
            == f"/api/v1/trials/{running['id']}/urdf"
        )
        assert browser.evaluate(f"{ROBOT_PIXELS}('{in_dialog}')") > 500
        browser.evaluate("document.querySelector('[data-trial-dialog] [data-close]').click()")
        browser.wait_for(
            f"document.querySelector('{in_dialog}').getContext('webgl2').isContextLost()"
        )

        # A new best: the card's view shows its robot instead.
        tell(http, running["id"], value=5.0)
        browser.wait_for(
            f"{model}.dataset.url === '/api/v1/trials/{running['id']}/urdf'"
            f" && document.querySelector('{view}').dataset.ready === 'true'"
        )
        assert browser.evaluate(f"{ROBOT_PIXELS}('{view}')") > 500
    assert f"{live_server.url}/vendor/three-urdf.js" in browser.requested
    assert all(url.startswith(live_server.url) for url in browser.requested)
    assert browser.errors == []


@pytest.mark.parametrize("database", ["sqlite"])
def test_a_box_studys_urdf_in_3d_fetches_nothing_it_names(
    live_server: ServerProcess, browser: Chromium
) -> None:
    """A box study's robot.urdf (uploaded by whoever ran the trial) is drawn from its
    primitive shapes; the mesh and the texture it names elsewhere are not fetched, and the
    view says the mesh is missing."""
    urdf = b"""<robot name="probe">
      <material name="blue"><color rgba="0.15 0.35 0.9 1"/>
        <texture filename="https://elsewhere.invalid/skin.png"/></material>
      <link name="base"><visual><geometry><box size="0.4 0.3 0.2"/></geometry>
        <material name="blue"/></visual></link>
      <link name="arm"><visual><geometry><mesh filename="https://elsewhere.invalid/arm.stl"/>
        </geometry></visual></link>
      <joint name="shoulder" type="revolute"><parent link="base"/><child link="arm"/>
        <axis xyz="0 0 1"/><limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
    </robot>"""
    body = {key: value for key, value in MANAGED_BOX.items() if key not in ("task", "max_trials")}
    with httpx.Client(base_url=live_server.url, timeout=30) as http:
        study = http.post("/api/v1/studies", json=dict(body, name="box-urdf")).raise_for_status()
        study_id = study.json()["id"]
        trial = http.post(f"/api/v1/studies/{study_id}/ask", json={}).json()["trials"][0]
        response = http.put(
            f"/api/v1/trials/{trial['id']}/artifacts/robot.urdf",
            content=urdf,
            headers={"Content-Type": "application/xml", "X-Activedesign-Client": "test"},
        )
        assert response.status_code == 201, response.text
        tell(http, trial["id"], value=1.0)

    browser.navigate(f"{live_server.url}/#/studies/{study_id}")
    browser.wait_for(STUDY_PAGE_READY)
    view = "[data-best-card] [data-robot-canvas]"
    browser.wait_for(f"document.querySelector('{view}')?.dataset.ready === 'true'", timeout=60)
    assert (
        browser.evaluate("document.querySelector('[data-best-card] .robot-view').dataset.url")
        == f"/api/v1/trials/{trial['id']}/artifacts/robot.urdf"
    )
    assert browser.evaluate(f"document.querySelector('{view}').dataset.joints") == "1"
    assert browser.evaluate(f"{ROBOT_PIXELS}('{view}')") > 500  # the blue box
    note = browser.evaluate(
        "document.querySelector('[data-best-card] [data-robot-note]').textContent"
    )
    assert note.startswith("1 mesh file(s) not drawn")
    assert [url for url in browser.requested if "elsewhere" in url] == []
    assert all(url.startswith((live_server.url, "data:")) for url in browser.requested)
    assert browser.errors == []
