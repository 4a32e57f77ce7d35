"""The params panel's Importance and Contour tabs (issue 29) in a real headless Chromium
against a real ``adserver``: PED-ANOVA importances computed in the page rank the param
that drives the score first and the one it ignores last, and equal Optuna's own
``PedAnovaImportanceEvaluator`` on the same trials; the contour draws the score over the
two most important params, and its selects redraw it over the pair picked; too few trials
get a message, not a chart, until enough are told; a param of one value has importance
0; a design study's params are its spec names, as the chart columns have them.

One server and one browser serve the module (conftest's ``shared_server``; the Pareto
tests' browser and client fixtures): each test makes its own studies. SQLite alone: the
page computes from the chart columns, which tests/service/test_dashboard_api.py and
test_dashboard_reads.py (a design study's spec names) assert on both databases.
"""

from __future__ import annotations

import json
import math
import time
from typing import Any, Literal

import httpx
import optuna
import pytest
import yaml
from optuna.distributions import (
    BaseDistribution,
    CategoricalDistribution,
    FloatDistribution,
)
from optuna.importance import PedAnovaImportanceEvaluator, get_param_importances

from adclient.testing.servers import ServerProcess
from tests.service.chromium import Chromium
from tests.service.dashboard_pages import (
    COUNT_PIXELS,
    DISPLAY,
    EXAMPLES,
    STUDY_PAGE_READY,
    tell,
)

pytestmark = [
    pytest.mark.browser,
    pytest.mark.e2e,
    pytest.mark.xdist_group("browser"),
    # PostgreSQL's columns: test_dashboard_api (box) and test_dashboard_reads (design).
    pytest.mark.parametrize("shared_server", ["sqlite"], indirect=True),
]

CHOICES = ["relu", "tanh", "gelu"]
SPACE = {
    "type": "box",
    "params": [
        {"name": "drive", "low": 0.0, "high": 1.0},
        {"name": "rate", "low": 0.001, "high": 1.0, "log": True},
        {"name": "act", "type": "categorical", "choices": CHOICES},
        {"name": "dead", "low": -1.0, "high": 1.0},
    ],
}
DISTRIBUTIONS: dict[str, BaseDistribution] = {
    "drive": FloatDistribution(0.0, 1.0),
    "rate": FloatDistribution(0.001, 1.0, log=True),
    "act": CategoricalDistribution(CHOICES),
    "dead": FloatDistribution(-1.0, 1.0),
}
N = 30
ROWS = (
    "[...document.querySelectorAll('[data-importance] .importance-row')]"
    ".map(row => [row.dataset.param, parseFloat(row.querySelector('.num').textContent)])"
)
CONTOUR = "document.querySelector('[data-contour-canvas]')"
YELLOW = [253, 231, 37]  # the palette's best level
PURPLE = [68, 1, 84]  # its worst


def score(params: dict[str, Any]) -> float:
    """Mostly ``drive`` (best at 0.7), a little ``rate`` and ``act``, never ``dead``."""
    return (
        -40 * (params["drive"] - 0.7) ** 2
        + 0.5 * math.log10(params["rate"])
        + 0.3 * CHOICES.index(params["act"])
    )


def design() -> list[dict[str, Any]]:
    """30 trials on a balanced grid: each numeric param takes each of 30 strata once, and
    ``dead`` is spread evenly over the trials in order of score (so its values among the
    top 3 are spread as all of them are). With only 3 top trials, random values would
    let chance cluster the top trials of any param and make it look important: that is
    PED-ANOVA with 30 trials, not the page."""
    trials = [
        {
            "drive": round(((i * 11) % N + 0.5) / N, 4),
            "rate": round(10 ** (-3 + 3 * ((i * 7) % N + 0.5) / N), 6),
            "act": CHOICES[i % 3],
        }
        for i in range(N)
    ]
    for rank, i in enumerate(sorted(range(N), key=lambda i: -score(trials[i]))):
        trials[i]["dead"] = round(-1 + 2 * ((rank * 13) % N + 0.5) / N, 4)
    return trials


def optuna_importances(
    series: dict[str, Any], direction: Literal["minimize", "maximize"]
) -> dict[str, float]:
    """Optuna's PED-ANOVA (its defaults) over the complete trials of the chart columns."""
    optuna.logging.set_verbosity(optuna.logging.ERROR)
    study = optuna.create_study(direction=direction)
    for k, state in enumerate(series["state"]):
        if state != "complete":
            continue
        params = {name: column[k] for name, column in series["params"].items()}
        trial = optuna.trial.create_trial(
            params=params, distributions=DISTRIBUTIONS, value=series["value"][k]
        )
        study.add_trial(trial)
    return get_param_importances(study, evaluator=PedAnovaImportanceEvaluator())


@pytest.fixture(scope="module")
def server(shared_server: ServerProcess) -> ServerProcess:
    """What the shared browser and client fixtures use: conftest's."""
    return shared_server


def tell_designs(http: httpx.Client, study_id: int, designs: list[dict[str, Any]]) -> None:
    """Enqueue the designs, ask for them (the queue comes first) and tell their scores."""
    queued = http.post(f"/api/v1/studies/{study_id}/trials", json=[{"params": d} for d in designs])
    assert queued.status_code == 201, queued.text
    asked = http.post(f"/api/v1/studies/{study_id}/ask", json={"count": len(designs)})
    trials = asked.raise_for_status().json()["trials"]
    assert [t["params"] for t in trials] == designs
    for trial in trials:
        tell(http, trial["id"], value=score(trial["params"]))


def open_study(browser: Chromium, server: ServerProcess, study_id: int, tab: str) -> None:
    """The study's page (not the last one's: each study here has its own name), on `tab`."""
    name = httpx.get(f"{server.url}/api/v1/studies/{study_id}", timeout=30).json()["name"]
    browser.navigate(f"{server.url}/#/studies/{study_id}")
    browser.wait_for(
        f"document.querySelector('.study [data-name]')?.textContent === {json.dumps(name)}"
        f" && {STUDY_PAGE_READY}"
    )
    browser.evaluate(f"document.querySelector('button[data-tab=\"{tab}\"]').click()")


def pick(browser: Chromium, axis: str, name: str) -> None:
    """Choose `name` in the contour's x or y select, as a person does."""
    browser.evaluate(
        f"(() => {{ const select = document.querySelector('[data-contour-{axis}]');"
        f" select.value = {json.dumps(name)};"
        " select.dispatchEvent(new Event('change')); })()"
    )


def spreads(browser: Chromium) -> tuple[float, float]:
    """How much the contour's interpolated score moves across (the range of its column
    means) and up (the range of its row means)."""
    z = browser.evaluate(f"{CONTOUR}.grid.z")
    rows = [sum(row) / len(row) for row in z]
    columns = [sum(row[k] for row in z) / len(z) for k in range(len(z[0]))]
    return max(columns) - min(columns), max(rows) - min(rows)


def test_importance_ranks_the_driving_param_first_and_agrees_with_optuna_and_the_contour_follows_its_selects(  # noqa: E501
    server: ServerProcess, browser: Chromium, http: httpx.Client
) -> None:
    body = {"name": "importance", "direction": "maximize", "space": SPACE}
    body["proposer"] = {"name": "random", "seed": 3}
    study_id = http.post("/api/v1/studies", json=body).raise_for_status().json()["id"]
    tell_designs(http, study_id, design())
    series = http.get(f"/api/v1/dashboard/studies/{study_id}/series").raise_for_status().json()
    expected = optuna_importances(series, "maximize")

    open_study(browser, server, study_id, "importance")
    rows = browser.wait_for(ROWS)
    names = [name for name, _ in rows]
    assert names[0] == "drive" and names[-1] == "dead", rows
    assert sorted(names) == sorted(DISTRIBUTIONS)
    assert names == sorted(names, key=lambda name: -expected[name])
    shown = json.loads(
        browser.evaluate("document.querySelector('[data-importance]').dataset.importances")
    )
    assert shown == pytest.approx(expected, rel=1e-4, abs=1e-7)
    assert sum(shown.values()) == pytest.approx(1)
    assert [value for _, value in rows] == [round(expected[name], 3) for name in names]
    method = browser.evaluate("document.querySelector('[data-importance-method]').textContent")
    assert "PED-ANOVA, top 10%" in " ".join(method.split())
    assert "the 3 complete trials with the highest score of 30" in " ".join(method.split())
    why = browser.evaluate("document.querySelector('[data-importance-why]').textContent")
    assert "tens of trials" in why and "linear in the trials" in why and "local" in why
    assert browser.evaluate(f"{DISPLAY}('[data-importance]')") == "block"
    assert browser.evaluate(f"{DISPLAY}('[data-parallel]')") == "none"

    # The contour: by default over the two most important params, drive across.
    browser.evaluate("document.querySelector('button[data-tab=\"contour\"]').click()")
    assert browser.evaluate(f"{DISPLAY}('[data-importance]')") == "none"
    assert browser.wait_for(f"{CONTOUR}.dataset.x") == names[0] == "drive"
    assert browser.evaluate(f"{CONTOUR}.dataset.y") == names[1]
    assert browser.evaluate(f"{CONTOUR}.dataset.points") == str(N)
    assert browser.evaluate(f"{CONTOUR}.dataset.cells") == "60x60"
    assert browser.evaluate("document.querySelector('[data-contour-y]').value") == names[1]
    values = [score(d) for d in design()]
    assert float(browser.evaluate(f"{CONTOUR}.dataset.low")) == pytest.approx(min(values))
    assert float(browser.evaluate(f"{CONTOUR}.dataset.high")) == pytest.approx(max(values))
    assert browser.evaluate(f"{COUNT_PIXELS}('[data-contour-canvas]', {YELLOW}, 2)") > 200
    assert browser.evaluate(f"{COUNT_PIXELS}('[data-contour-canvas]', {PURPLE}, 2)") > 200
    legend = browser.evaluate("document.querySelector('[data-contour-legend]').textContent")
    assert "yellow = best (highest)" in " ".join(legend.split())
    assert (
        browser.evaluate("document.querySelectorAll('[data-contour-legend] .swatches i').length")
        == 10
    )

    # The score moves with drive and not with dead: across far more than up.
    pick(browser, "y", "dead")
    assert browser.wait_for(f"{CONTOUR}.dataset.y === 'dead' && {CONTOUR}.dataset.x") == "drive"
    across, up = spreads(browser)
    assert across > 5 * up, (across, up)
    # The grid's score peaks near drive = 0.7, where the score does.
    z = browser.evaluate(f"{CONTOUR}.grid.z")
    xs = browser.evaluate(f"{CONTOUR}.grid.x")
    means = [sum(row[k] for row in z) / len(z) for k in range(len(xs))]
    assert abs(xs[means.index(max(means))] - 0.7) < 0.1

    # Turned around: dead across, drive up.
    pick(browser, "x", "dead")
    assert browser.wait_for(f"{CONTOUR}.dataset.x === 'dead' && {CONTOUR}.dataset.y") == "drive"
    across, up = spreads(browser)
    assert up > 5 * across, (across, up)

    # A categorical param: one band per choice, in the space's order.
    pick(browser, "x", "act")
    assert browser.wait_for(f"{CONTOUR}.dataset.x === 'act' && {CONTOUR}.dataset.cells") == "3x60"
    assert browser.evaluate(f"{CONTOUR}.grid.x") == [0, 1, 2]
    assert browser.evaluate("document.querySelector('[data-contour-x]').value") == "act"

    # A log param: its cells even on a log scale (each a constant ratio wider).
    pick(browser, "x", "rate")
    assert browser.wait_for(f"{CONTOUR}.dataset.x === 'rate'")
    centres = browser.evaluate(f"{CONTOUR}.grid.x")
    assert centres[0] == pytest.approx(-3 + 1.5 / 60) and centres[-1] == pytest.approx(-1.5 / 60)

    # Hovering a trial names it and its score; elsewhere, the interpolated score.
    point = browser.evaluate(f"{CONTOUR}.hit.points[0]")
    hover = (
        f"((x, y) => {{ const canvas = {CONTOUR}; const box = canvas.getBoundingClientRect();"
        " canvas.dispatchEvent(new MouseEvent('mousemove', {clientX: box.left + x,"
        " clientY: box.top + y, bubbles: true}));"
        " return document.querySelector('[data-contour] [data-tooltip]').textContent; })"
    )
    tip = browser.evaluate(f"{hover}({point['x']}, {point['y']})")
    assert f"trial #{point['number']}" in tip and "rate =" in tip and "drive =" in tip
    area = browser.evaluate(f"{CONTOUR}.hit.area")
    corner = (area["right"] - 2, area["top"] + 2)
    points = browser.evaluate(f"{CONTOUR}.hit.points")
    assert all((p["x"] - corner[0]) ** 2 + (p["y"] - corner[1]) ** 2 > 100 for p in points)
    assert "(interpolated)" in browser.evaluate(f"{hover}({corner[0]}, {corner[1]})")
    assert browser.errors == []


def test_too_few_trials_get_a_message_until_enough_are_told_and_a_fixed_param_counts_zero(
    server: ServerProcess, browser: Chromium, http: httpx.Client
) -> None:
    space = {
        "type": "box",
        "params": [*SPACE["params"], {"name": "fixed", "low": 0.0, "high": 1.0}],
    }
    body = {"name": "few", "direction": "minimize", "space": space}
    study_id = http.post("/api/v1/studies", json=body).raise_for_status().json()["id"]
    designs = [{**d, "fixed": 0.5} for d in design()]
    tell_designs(http, study_id, designs[:5])

    open_study(browser, server, study_id, "importance")
    message = browser.wait_for("document.querySelector('[data-importance-message]')?.textContent")
    assert message == (
        "Parameter importance (PED-ANOVA) needs at least 10 complete trials; this study has 5."
    )
    assert browser.evaluate(ROWS) == []
    assert browser.evaluate("document.querySelector('[data-importance]').dataset.status") == "few"
    # The contour draws from 3 trials on; the importance order is not there yet.
    browser.evaluate("document.querySelector('button[data-tab=\"contour\"]').click()")
    assert browser.wait_for(f"{CONTOUR}.dataset.points") == "5"
    pair = [browser.evaluate(f"{CONTOUR}.dataset.{axis}") for axis in "xy"]
    assert pair[0] != pair[1] and set(pair) <= set(DISTRIBUTIONS)
    assert browser.evaluate(f"{CONTOUR}.grid.z.flat().every(Number.isFinite)")
    options = browser.evaluate(
        "[...document.querySelectorAll('[data-contour-x] option')].map(o => o.value)"
    )
    assert sorted(options) == sorted(DISTRIBUTIONS)  # fixed never varies: not offered

    # More trials, told while the page watches: the next poll draws the importances.
    browser.evaluate("document.querySelector('button[data-tab=\"importance\"]').click()")
    tell_designs(http, study_id, designs[5:])
    rows = browser.wait_for(f"(() => {{ const rows = {ROWS}; return rows.length && rows; }})()")
    assert sorted(name for name, _ in rows) == sorted(DISTRIBUTIONS)  # fixed: not a bar
    fixed = browser.evaluate("document.querySelector('[data-importance-fixed]').textContent")
    assert " ".join(fixed.split()) == "One value in every complete trial (importance 0): fixed."
    shown = json.loads(
        browser.evaluate("document.querySelector('[data-importance]').dataset.importances")
    )
    assert shown["fixed"] == 0
    series = http.get(f"/api/v1/dashboard/studies/{study_id}/series").raise_for_status().json()
    series["params"].pop("fixed")
    expected = optuna_importances(series, "minimize")
    # The page may first draw from a poll made while the last trials were being told; its
    # next poll draws from all of them.
    deadline = time.monotonic() + 60
    while True:
        shown = json.loads(
            browser.evaluate("document.querySelector('[data-importance]').dataset.importances")
        )
        drawn = {k: v for k, v in shown.items() if k != "fixed"}
        if drawn == pytest.approx(expected, rel=1e-4, abs=1e-7) or time.monotonic() > deadline:
            break
        time.sleep(0.2)
    assert drawn == pytest.approx(expected, rel=1e-4, abs=1e-7)
    method = " ".join(
        browser.evaluate("document.querySelector('[data-importance-method]').textContent").split()
    )
    assert "the 3 complete trials with the lowest score of 30" in method
    assert browser.errors == []


def test_a_design_studys_importances_and_contour_are_over_its_spec_names(
    server: ServerProcess, browser: Chromium, http: httpx.Client
) -> None:
    body = yaml.safe_load((EXAMPLES / "stand-up.yaml").read_text())
    body.pop("task")
    body.update(name="design-importance", proposer={"name": "random", "seed": 2}, max_trials=40)
    study_id = http.post("/api/v1/studies", json=body).raise_for_status().json()["id"]
    asked = http.post(f"/api/v1/studies/{study_id}/ask", json={"count": 16})
    for trial in asked.raise_for_status().json()["trials"]:
        tell(http, trial["id"], value=-((trial["params"]["b.length"] - 0.5) ** 2))
    series = http.get(f"/api/v1/dashboard/studies/{study_id}/series").raise_for_status().json()
    varying = sorted(name for name, column in series["params"].items() if len(set(column)) > 1)
    fixed = sorted(set(series["params"]) - set(varying))
    assert "b.length" in varying and "a.radius" in fixed  # spec names, as the columns have them

    open_study(browser, server, study_id, "importance")
    rows = browser.wait_for(ROWS)
    assert sorted(name for name, _ in rows) == varying
    shown = json.loads(
        browser.evaluate("document.querySelector('[data-importance]').dataset.importances")
    )
    assert sorted(shown) == sorted(series["params"])
    assert sum(shown.values()) == pytest.approx(1)
    assert all(shown[name] == 0 for name in fixed)
    text = browser.evaluate("document.querySelector('[data-importance-fixed]').textContent")
    assert all(name in text for name in fixed)
    browser.evaluate("document.querySelector('button[data-tab=\"contour\"]').click()")
    x = browser.wait_for(f"{CONTOUR}.dataset.x")
    assert [x, browser.evaluate(f"{CONTOUR}.dataset.y")] == [name for name, _ in rows[:2]]
    assert browser.evaluate(f"{CONTOUR}.dataset.points") == "16"
    options = browser.evaluate(
        "[...document.querySelectorAll('[data-contour-y] option')].map(o => o.value)"
    )
    assert sorted(options) == varying
    assert browser.errors == []
