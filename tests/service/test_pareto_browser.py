"""The dashboard's Pareto panel (issue 17) in a real headless Chromium against a real
``adserver``: a managed study of two objectives with a
constraint draws its complete trials, the server's front (as many points as
``/pareto`` answers) and its infeasible trials greyed; hovering a design on the front
shows its picture and clicking a point opens that trial's dialog; the trials table has a
column per objective and marks infeasible trials; a study of three objectives lets one
pick the two axes; a study of one objective shows no Pareto panel (and, constrained,
greys and marks its infeasible trials). One server (conftest's ``shared_server``) and one
page (the test process's shared one) for the whole module, on SQLite: what PostgreSQL
changes, the chart columns and the front, tests/service/test_dashboard_reads.py asserts
on both databases."""

from __future__ import annotations

import random
from typing import Any

import httpx
import pytest

from adclient.testing.servers import ServerProcess
from tests.service.chromium import Chromium
from tests.service.dashboard_pages import (
    COUNT_PIXELS,
    lease,
    png,
    tell,
    upload,
)
from tests.service.fronts import brute_front

pytestmark = [
    pytest.mark.browser,
    pytest.mark.e2e,
    pytest.mark.xdist_group("browser"),
    # PostgreSQL's columns and front: test_dashboard_reads (two and three objectives).
    pytest.mark.parametrize("shared_server", ["sqlite"], indirect=True),
]

SPACE = {"type": "box", "params": [{"name": "x", "low": 0.0, "high": 1.0}]}
MASS_LIMIT = 3.0
GREY = [156, 163, 175]  # infeasible points (charts.js INFEASIBLE)
ORANGE = [234, 88, 12]  # the front
CANVAS = "canvas[data-pareto]"
HIT = f"document.querySelector('{CANVAS}').hit.points"


@pytest.fixture(scope="module")
def server(shared_server: ServerProcess) -> ServerProcess:
    """What the module's browser and client fixtures use: conftest's shared server."""
    return shared_server


@pytest.fixture(scope="module")
def two(http: httpx.Client) -> dict[str, Any]:
    """A managed study maximising speed and minimising mass, subject to mass <= 3: 14
    trials told by a worker with a picture each (some too heavy), one failed, one
    running."""
    body = {
        "name": "pareto-two",
        "space": SPACE,
        "proposer": {"name": "random", "seed": 5},
        "task": {"name": "noop", "external": True},
        "max_trials": 40,
        "directions": ["maximize", "minimize"],
        "objective_names": ["speed", "mass"],
        "constraints": [{"metric": "mass", "op": "<=", "bound": MASS_LIMIT}],
    }
    study = http.post("/api/v1/studies", json=body).raise_for_status().json()
    rng = random.Random(17)
    told: dict[int, list[float]] = {}
    ids: dict[int, int] = {}
    running: dict[str, Any] = {}
    for i in range(16):
        job = lease(http, "worker-1")
        if i == 5:
            tell(http, job["trial_id"], state="failed", worker_id="worker-1", message="fell")
            continue
        values = [round(rng.uniform(0, 10), 3), round(rng.uniform(0.5, 5), 3)]
        if i == 15:
            running = job  # left running
            break
        upload(http, job["trial_id"], "robot.png", png(40, 30), "image/png", "worker-1")
        tell(http, job["trial_id"], values=values, worker_id="worker-1")
        told[job["number"]] = values
        ids[job["number"]] = job["trial_id"]
    feasible = {n: v for n, v in told.items() if v[1] <= MASS_LIMIT}
    front = brute_front(feasible, [1.0, -1.0])
    assert 2 <= len(front) < len(feasible) < len(told)
    return {
        "study": study,
        "told": told,
        "ids": ids,
        "front": front,
        "feasible": feasible,
        "running": running,
    }


def open_study(browser: Chromium, server: ServerProcess, study: dict[str, Any]) -> None:
    browser.navigate(f"{server.url}/#/studies/{study['id']}")
    browser.wait_for(
        f"document.querySelector('.study [data-name]')?.textContent === {study['name']!r}"
        " && document.querySelector('.study')?.dataset.ready === 'true'"
    )


DRAWN_AT_ITS_SIZE = """((canvas) =>
  canvas.width === Math.round(canvas.clientWidth * devicePixelRatio)
  && canvas.height === Math.round(canvas.clientHeight * devicePixelRatio))"""
"""Whether a chart's points (its ``hit`` map) are where the page shows them: charts.js
``prepare`` sizes the canvas to its box at each draw, and a box that changed since (a
page that grew a scrollbar, before dashboard.css kept one) is redrawn only a moment
later."""


def point_at(browser: Chromium, number: int) -> tuple[float, float]:
    """Where trial ``number``'s point is on the screen (the chart scrolled into view),
    once the chart is drawn at the size it is shown."""
    x, y = browser.wait_for(
        f"(() => {{ const canvas = document.querySelector('{CANVAS}');"
        " canvas.scrollIntoView({block: 'center'});"
        f" if (!{DRAWN_AT_ITS_SIZE}(canvas)) return null;"
        " const box = canvas.getBoundingClientRect();"
        f" const p = {HIT}.find((p) => p.number === {number});"
        " return [box.x + p.x, box.y + p.y]; })()"
    )
    return x, y


def mouse(browser: Chromium, kind: str, x: float, y: float) -> None:
    buttons = {"button": "left", "clickCount": 1} if kind != "mouseMoved" else {}
    browser.send("Input.dispatchMouseEvent", type=kind, x=x, y=y, **buttons)


def click(browser: Chromium, x: float, y: float) -> None:
    mouse(browser, "mouseMoved", x, y)
    mouse(browser, "mousePressed", x, y)
    mouse(browser, "mouseReleased", x, y)


def close_dialog(browser: Chromium) -> None:
    browser.evaluate("document.querySelector('[data-trial-dialog] [data-close]').click()")
    browser.wait_for("!document.querySelector('[data-trial-dialog]').open")


def test_two_objectives_front_infeasible_and_table(
    server: ServerProcess, http: httpx.Client, browser: Chromium, two: dict[str, Any]
) -> None:
    sid = two["study"]["id"]
    # The chart's columns: values and feasibility of each trial, in order of number.
    series = http.get(f"/api/v1/dashboard/studies/{sid}/series").json()
    assert series["value"] == [None] * 16
    for number, values in two["told"].items():
        assert series["values"][number] == values
        assert series["feasible"][number] is (values[1] <= MASS_LIMIT)
    assert series["values"][5] is None and series["feasible"][5] is None  # failed
    pareto = http.get(f"/api/v1/studies/{sid}/pareto").json()
    assert {t["number"] for t in pareto} == two["front"]

    open_study(browser, server, two["study"])
    data = f"document.querySelector('{CANVAS}').dataset"
    assert browser.evaluate("!document.querySelector('[data-pareto-card]').hidden")
    assert browser.evaluate(f"[{data}.points, {data}.front, {data}.infeasible]") == [
        str(len(two["told"])),
        str(len(two["front"])),
        str(len(two["told"]) - len(two["feasible"])),
    ]
    assert browser.evaluate(f"{HIT}.filter((p) => p.front).map((p) => p.number)") == sorted(
        two["front"]
    )
    # Drawn: grey infeasible points and the orange front (points and its staircase).
    assert browser.evaluate(f"{COUNT_PIXELS}('{CANVAS}', {GREY}, 6)") > 20
    assert browser.evaluate(f"{COUNT_PIXELS}('{CANVAS}', {ORANGE}, 10)") > 100
    # Two objectives: no axis selectors, the staircase's key shown.
    assert browser.evaluate("document.querySelector('[data-pareto-axes]').hidden")
    assert not browser.evaluate("document.querySelector('[data-pareto-line]').hidden")
    count = browser.evaluate("document.querySelector('[data-pareto-count]').textContent")
    assert count == f"{len(two['front'])} of {len(two['told'])} complete trials"
    # The summary counts the front instead of a best value.
    assert browser.evaluate("document.querySelector('[data-best-title]').textContent") == (
        "Pareto front"
    )
    assert browser.evaluate(
        "document.querySelector('[data-front-count]').textContent.trim()"
    ) == str(len(two["front"]))

    # The table: a column per objective (no score), infeasible trials marked, the front starred.
    heads = browser.evaluate(
        "[...document.querySelectorAll('[data-trials] thead th')].map((th) => th.textContent)"
    )
    assert heads[:4] == ["#", "State", "speed ↑", "mass ↓"] and "Score" not in heads
    rows = browser.evaluate(
        "[...document.querySelectorAll('[data-trials] tbody tr[data-trial-id]')].map((row) =>"
        " [parseInt(row.cells[0].textContent), !!row.querySelector('.badge.infeasible'),"
        " row.classList.contains('is-best'), row.cells[2].textContent, row.cells[3].textContent])"
    )
    by_number = {row[0]: row[1:] for row in rows}
    for number, values in two["told"].items():
        infeasible, starred, speed, mass = by_number[number]
        assert infeasible is (values[1] > MASS_LIMIT)
        assert starred is (number in two["front"])
        assert float(speed) == pytest.approx(values[0], rel=1e-3)
        assert float(mass) == pytest.approx(values[1], rel=1e-3)

    # Hovering a design on the front: its number, values and picture.
    number = min(two["front"])
    x, y = point_at(browser, number)
    mouse(browser, "mouseMoved", x, y)
    tooltip = "document.querySelector('[data-pareto-card] [data-tooltip]')"
    browser.wait_for(f"!{tooltip}.hidden")
    text = browser.evaluate(f"{tooltip}.textContent")
    assert f"trial #{number} · on the front" in text and "speed" in text, text
    assert (
        browser.wait_for(
            f"(() => {{ const img = {tooltip}.querySelector('img.thumb');"
            " return img && img.complete && img.naturalWidth; })()"
        )
        == 40
    )

    # Clicking it opens its trial's dialog, with its picture and values.
    click(browser, *point_at(browser, number))
    dialog = "document.querySelector('[data-trial-dialog]')"
    browser.wait_for(f"{dialog}.open && {dialog}.textContent.includes('Trial #{number} ')")
    assert (
        browser.wait_for(
            f"(() => {{ const img = {dialog}.querySelector('[data-trial-image]');"
            " return img && img.complete && img.naturalWidth; })()"
        )
        == 40
    )
    assert browser.evaluate(f"!!{dialog}.querySelector('[data-trial-values]')")
    assert (
        browser.evaluate(f"{dialog}.querySelector('[data-trial-feasible]').dataset.trialFeasible")
        == "true"
    )
    close_dialog(browser)

    # And an infeasible point opens its own.
    heavy = min(n for n, v in two["told"].items() if v[1] > MASS_LIMIT)
    click(browser, *point_at(browser, heavy))
    browser.wait_for(f"{dialog}.open && {dialog}.textContent.includes('Trial #{heavy} ')")
    assert (
        browser.evaluate(f"{dialog}.querySelector('[data-trial-feasible]').dataset.trialFeasible")
        == "false"
    )
    close_dialog(browser)

    # The running trial ends better in both: the next poll's delta makes it the whole front.
    job = two["running"]
    tell(http, job["trial_id"], values=[20.0, 0.25], worker_id="worker-1")
    browser.wait_for(f"{data}.front === '1' && {data}.points === '{len(two['told']) + 1}'")
    assert browser.evaluate(f"{HIT}.filter((p) => p.front).map((p) => p.number)") == [job["number"]]
    assert browser.evaluate(f"{data}.infeasible") == str(len(two["told"]) - len(two["feasible"]))
    assert browser.errors == []


def test_three_objectives_pick_the_axes(
    server: ServerProcess, http: httpx.Client, browser: Chromium
) -> None:
    body = {
        "name": "pareto-three",
        "space": SPACE,
        "proposer": {"name": "random", "seed": 2},
        "directions": ["maximize", "minimize", "maximize"],
        "objective_names": ["reach", "effort", "lift"],
    }
    study = http.post("/api/v1/studies", json=body).raise_for_status().json()
    trials = http.post(f"/api/v1/studies/{study['id']}/ask", json={"count": 9}).json()["trials"]
    rng = random.Random(4)
    told = {}
    for trial in trials:
        values = [round(rng.uniform(-5, 5), 3) for _ in range(3)]
        tell(http, trial["id"], values=values)
        told[trial["number"]] = values
    front = brute_front(told, [1.0, -1.0, 1.0])

    open_study(browser, server, study)
    data = f"document.querySelector('{CANVAS}').dataset"
    assert browser.evaluate(f"[{data}.points, {data}.front, {data}.axes]") == [
        "9",
        str(len(front)),
        "0,1",
    ]
    assert not browser.evaluate("document.querySelector('[data-pareto-axes]').hidden")
    assert browser.evaluate("document.querySelector('[data-pareto-line]').hidden")

    def order(k: int) -> list[int]:
        """Trial numbers left to right, as objective ``k`` orders them."""
        return [n for n, _ in sorted(told.items(), key=lambda item: (item[1][k], item[0]))]

    def drawn(axis: str) -> list[int]:
        return browser.evaluate(
            f"{HIT}.slice().sort((a, b) => a.{axis} - b.{axis} || a.number - b.number)"
            ".map((p) => p.number)"
        )

    assert drawn("x") == order(0)

    def choose(which: str, k: int) -> None:
        browser.evaluate(
            f"(() => {{ const s = document.querySelector('[data-pareto-{which}]');"
            f" s.value = '{k}'; s.dispatchEvent(new Event('change')); }})()"
        )

    choose("x", 2)
    assert browser.evaluate(f"{data}.axes") == "2,1"
    assert drawn("x") == order(2)
    # The y axis onto the x one's objective: the two swap.
    choose("y", 2)
    assert browser.evaluate(f"{data}.axes") == "1,2"
    assert drawn("x") == order(1)
    assert list(reversed(drawn("y"))) == order(2)  # y grows upwards
    heads = browser.evaluate(
        "[...document.querySelectorAll('[data-trials] thead th')].map((th) => th.textContent)"
    )
    assert heads[2:5] == ["reach ↑", "effort ↓", "lift ↑"]
    assert browser.errors == []


def test_one_objective_shows_no_pareto_panel(
    server: ServerProcess, http: httpx.Client, browser: Chromium
) -> None:
    body = {"name": "pareto-none", "space": SPACE, "proposer": {"name": "random", "seed": 3}}
    study = http.post("/api/v1/studies", json=body).raise_for_status().json()
    for i, trial in enumerate(
        http.post(f"/api/v1/studies/{study['id']}/ask", json={"count": 4}).json()["trials"]
    ):
        tell(http, trial["id"], value=float(i))
    series = http.get(f"/api/v1/dashboard/studies/{study['id']}/series").json()
    assert series["values"] is None and series["feasible"] is None

    open_study(browser, server, study)
    assert browser.evaluate("document.querySelector('[data-pareto-card]').hidden")
    assert browser.evaluate("document.querySelector('[data-best-title]').textContent") == (
        "Best design"
    )
    heads = browser.evaluate(
        "[...document.querySelectorAll('[data-trials] thead th')].map((th) => th.textContent)"
    )
    assert heads[:3] == ["#", "State", "Score"]
    assert browser.evaluate("document.querySelector('canvas[data-history]').dataset.points") == "4"
    # Its score chart's hover names a trial and its score, as it always did.
    x, y = browser.wait_for(
        "(() => { const c = document.querySelector('canvas[data-history]');"
        f" c.scrollIntoView({{block: 'center'}}); if (!{DRAWN_AT_ITS_SIZE}(c)) return null;"
        " const box = c.getBoundingClientRect();"
        " return [box.x + c.hit.x(2), box.y + c.hit.y(2)]; })()"
    )
    mouse(browser, "mouseMoved", x, y)
    tooltip = "document.querySelector('canvas[data-history] + [data-tooltip]')"
    browser.wait_for(f"!{tooltip}.hidden")
    assert browser.evaluate(f"{tooltip}.textContent") == "trial #2: 2"

    # Under a constraint, one objective still has no Pareto panel; its breaches are marked.
    body |= {"name": "pareto-none-constrained"}
    body["constraints"] = [{"metric": "mass", "op": "<=", "bound": 1.0}]
    constrained = http.post("/api/v1/studies", json=body).raise_for_status().json()
    asked = http.post(f"/api/v1/studies/{constrained['id']}/ask", json={"count": 4}).json()
    for i, trial in enumerate(asked["trials"]):
        tell(http, trial["id"], value=float(i), metrics={"mass": 0.5 + i / 3})  # 2 and 3 heavy
    open_study(browser, server, constrained)
    assert browser.evaluate("document.querySelector('[data-pareto-card]').hidden")
    history = "document.querySelector('canvas[data-history]').dataset"
    assert browser.evaluate(f"[{history}.points, {history}.infeasible, {history}.bestSoFar]") == [
        "4",
        "2",
        "1",  # the best feasible
    ]
    marked = browser.evaluate(
        "[...document.querySelectorAll('[data-trials] tbody tr[data-trial-id]')]"
        ".filter((row) => row.querySelector('.badge.infeasible'))"
        ".map((row) => parseInt(row.cells[0].textContent))"
    )
    assert sorted(marked) == [2, 3]
    assert browser.errors == []
