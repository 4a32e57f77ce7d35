"""Exploring a study on the dashboard (issue 62, against optuna-dashboard; issue 60's
score spread) in a real headless Chromium against a real ``adserver``: the per-param
plots of a design study show what was searched (a tie or mirror once, the structure and
catalogue choices as choice axes, as the best design card counts them); the contour
greys what no trial explored instead of painting it a score; filters by a param's and
the score's range (typed, or brushed on a parallel-coordinates axis) narrow the trial
table and the plots; the empirical distribution plot; studies compared side by side at
their own address, Back and Forward included; notes on a study and on a trial kept as
text; the spread of a trial's score over its evaluation episodes beside it.

One server (conftest's ``shared_server``) and one browser page serve the module; each
test makes its own studies. SQLite alone: the chart columns of a design study are
asserted on both databases by tests/service/test_dashboard_reads.py, the notes by
tests/service/test_notes_api.py.
"""

from __future__ import annotations

import json
import re
from typing import Any

import httpx
import pytest
import yaml

from adclient.testing.servers import ServerProcess
from tests.service.chromium import Chromium
from tests.service.dashboard_pages import (
    COUNT_PIXELS,
    EXAMPLES,
    STUDY_PAGE_READY,
    tell,
)

pytestmark = [
    pytest.mark.browser,
    pytest.mark.e2e,
    pytest.mark.xdist_group("browser"),
    pytest.mark.parametrize("shared_server", ["sqlite"], indirect=True),
]

PARALLEL = "document.querySelector('[data-parallel]')"
CONTOUR = "document.querySelector('[data-contour-canvas]')"
TOTAL = "document.querySelector('[data-trials]').dataset.total"
ROW_NUMBERS = (
    "[...document.querySelectorAll('[data-trials] tbody tr[data-trial-id]')]"
    ".map(row => parseInt(row.cells[0].textContent))"
)
GREY = [209, 213, 219]  # the contour's unexplored cells
BOX = {"type": "box", "params": [{"name": n, "low": 0.0, "high": 1.0} for n in ("x", "y")]}


@pytest.fixture(scope="module")
def server(shared_server: ServerProcess) -> ServerProcess:
    return shared_server


def box_study(http: httpx.Client, name: str, points: list[tuple[float, float]], **body: Any) -> int:
    """A box study over x and y whose trials are `points`, each told score x + y."""
    created = {"name": name, "direction": "maximize", "space": BOX, **body}
    study_id = int(http.post("/api/v1/studies", json=created).raise_for_status().json()["id"])
    designs = [{"params": {"x": x, "y": y}} for x, y in points]
    http.post(f"/api/v1/studies/{study_id}/trials", json=designs).raise_for_status()
    asked = http.post(f"/api/v1/studies/{study_id}/ask", json={"count": len(points)})
    for trial in asked.raise_for_status().json()["trials"]:
        tell(http, trial["id"], value=trial["params"]["x"] + trial["params"]["y"])
    return study_id


def open_study(browser: Chromium, server: ServerProcess, study_id: int) -> None:
    browser.navigate(f"{server.url}/#/studies/{study_id}")
    browser.wait_for(
        f"document.querySelector('.study [data-name]')?.textContent && {STUDY_PAGE_READY}"
        f" && location.hash === '#/studies/{study_id}'"
    )


def tab(browser: Chromium, name: str) -> None:
    browser.evaluate(f"document.querySelector('button[data-tab=\"{name}\"]').click()")


def design_study(http: httpx.Client, example: str, trials: int) -> tuple[int, list[str]]:
    """A study of examples/`example`.yaml (no task), `trials` random designs told; its id
    and the chart columns of what it searched that vary (a searched axis by its angles)."""
    body = yaml.safe_load((EXAMPLES / f"{example}.yaml").read_text())
    body.pop("task", None)
    body.update(name=f"searched-{example}", proposer={"name": "random", "seed": 5})
    study = http.post("/api/v1/studies", json=body).raise_for_status().json()
    asked = http.post(f"/api/v1/studies/{study['id']}/ask", json={"count": trials})
    for k, trial in enumerate(asked.raise_for_status().json()["trials"]):
        tell(http, trial["id"], value=float(k % 5))
    searched = set(study["searched_params"])
    columns = http.get(f"/api/v1/dashboard/studies/{study['id']}/series").json()["params"]
    return int(study["id"]), sorted(
        name
        for name, column in columns.items()
        if (name in searched or re.sub(r"_(theta|phi)$", "", name) in searched)
        and len(set(column)) > 1
    )


def test_a_design_studys_plots_show_each_searched_param_once_with_choices_on_their_own_axes(
    server: ServerProcess, browser: Chromium, http: httpx.Client
) -> None:
    # The quadruped's right legs mirror its left ones: one axis per searched spec.
    study_id, searched = design_study(http, "quadruped", 10)
    assert "front_left.length" in searched and "front_left.joint.axis_phi" in searched
    assert not [name for name in searched if name.startswith("front_right")]
    searched_params = http.get(f"/api/v1/studies/{study_id}").json()["searched_params"]
    open_study(browser, server, study_id)
    axes = json.loads(browser.wait_for(f"{PARALLEL}.dataset.axes"))
    assert sorted(axes) == searched, axes
    tab(browser, "slices")
    figures = browser.evaluate(
        "[...document.querySelectorAll('[data-slices] figcaption')].map(c => c.textContent)"
    )
    assert sorted(figures) == searched
    tab(browser, "correlation")
    names = browser.evaluate(
        "[...document.querySelectorAll('[data-correlation] .name')].map(n => n.textContent)"
    )
    assert sorted(names) == searched
    note = browser.evaluate("document.querySelector('[data-best-note]')?.textContent ?? ''")
    assert f"the {len(searched_params)} searched params" in " ".join(note.split())

    # A catalogue's choice is an axis of its choices (the servos' names).
    study_id, searched = design_study(http, "catalogue-arm", 12)
    catalogue = yaml.safe_load((EXAMPLES / "catalogue-arm.yaml").read_text())["space"]
    servos = set(catalogue["catalogues"]["servos"])
    open_study(browser, server, study_id)
    axes = json.loads(browser.wait_for(f"{PARALLEL}.dataset.axes"))
    assert sorted(axes) == searched and "b.joint.choice" in axes
    ticks = json.loads(browser.evaluate(f"{PARALLEL}.dataset.ticks"))
    assert ticks["b.joint.choice"] and set(ticks["b.joint.choice"]) <= servos

    # Several structures: the structure is an axis of the trees the trials took.
    study_id, searched = design_study(http, "multi-structure", 12)
    open_study(browser, server, study_id)
    axes = json.loads(browser.wait_for(f"{PARALLEL}.dataset.axes"))
    assert "structure" in axes and set(axes) <= set(searched)
    series = http.get(f"/api/v1/dashboard/studies/{study_id}/series").json()
    trees = set(series["params"]["structure"])
    assert len(trees) > 1
    assert set(json.loads(browser.evaluate(f"{PARALLEL}.dataset.ticks"))["structure"]) == trees
    assert browser.errors == []


def test_the_contour_greys_what_no_trial_explored_and_says_so(
    server: ServerProcess, browser: Chromium, http: httpx.Client
) -> None:
    # Trials only in the corner x, y <= 0.3; the best of them at (0.3, 0.3).
    points = [(0.1 * i, 0.1 * j) for i in range(4) for j in range(4)]
    study_id = box_study(http, "unexplored", points)
    open_study(browser, server, study_id)
    tab(browser, "contour")
    assert browser.wait_for(f"{CONTOUR}.dataset.points") == str(len(points))
    explored = browser.evaluate(f"{CONTOUR}.grid.explored")
    assert explored[0][0] and explored[10][10]  # among the trials
    assert not explored[59][59] and not explored[0][59]  # far from every trial
    unexplored = int(browser.evaluate(f"{CONTOUR}.dataset.unexplored"))
    assert unexplored == sum(not cell for row in explored for cell in row)
    assert 2000 < unexplored < 3600  # 60 x 60 cells, the trials' corner about a fifth
    assert browser.evaluate(f"{COUNT_PIXELS}('[data-contour-canvas]', {GREY}, 1)") > 10_000
    legend = " ".join(
        browser.evaluate("document.querySelector('[data-contour-legend]').textContent").split()
    )
    assert "unexplored: no trial within 15% of the axes' ranges" in legend
    assert browser.errors == []


def brush(browser: Chromium, axis: str, low: float, high: float) -> None:
    """Drag along the parallel coordinates' `axis` from value `high` down to `low`."""
    browser.evaluate(
        f"""(() => {{
        const canvas = {PARALLEL};
        const {{ top, bottom, list }} = canvas.axes;
        const axis = list.find((a) => a.name === {json.dumps(axis)});
        const [lo, hi] = axis.range;
        const at = (v) => bottom - ((v - lo) / (hi - lo)) * (bottom - top);
        const box = canvas.getBoundingClientRect();
        const event = (type, v) => new MouseEvent(type, {{ clientX: box.left + axis.x,
          clientY: box.top + at(v), bubbles: true }});
        canvas.dispatchEvent(event('mousedown', {high}));
        window.dispatchEvent(event('mouseup', {low}));
      }})()"""
    )


def table_params(browser: Chromium) -> list[dict[str, float]]:
    texts = browser.evaluate(
        "[...document.querySelectorAll('[data-trials] tbody tr[data-trial-id] td.params')]"
        ".map(cell => cell.textContent)"
    )
    return [{k: float(v) for k, v in re.findall(r"(\w+)=([-\d.e]+)", text)} for text in texts]


def test_filters_by_a_params_range_typed_or_brushed_narrow_the_table_and_the_plots(
    server: ServerProcess, browser: Chromium, http: httpx.Client
) -> None:
    points = [(((i * 7) % 30 + 0.5) / 30, ((i * 11) % 30 + 0.5) / 30) for i in range(30)]
    study_id = box_study(http, "filtered", points)
    open_study(browser, server, study_id)
    assert browser.wait_for(TOTAL) == "30"
    browser.evaluate(
        """(() => { const form = document.querySelector('[data-range-form]');
        form.querySelector('[data-range-name]').value = 'x';
        form.querySelector('[data-range-low]').value = '0.25';
        form.querySelector('[data-range-high]').value = '0.75';
        form.requestSubmit(); })()"""
    )
    inside = [p for p in points if 0.25 <= p[0] <= 0.75]
    assert browser.wait_for(f"{TOTAL} === '{len(inside)}' && {TOTAL}") == str(len(inside))
    rows = table_params(browser)
    assert len(rows) == len(inside) and all(0.25 <= row["x"] <= 0.75 for row in rows)
    assert browser.evaluate(f"{PARALLEL}.dataset.passing") == str(len(inside))
    chips = browser.evaluate("document.querySelector('[data-filters]').textContent")
    assert "x in [0.25, 0.75]" in chips

    # Brushing y's axis adds its range: the table and the lines follow both filters.
    brush(browser, "y", 0.2, 0.6)
    browser.wait_for("document.querySelectorAll('[data-filters] [data-clear-filter]').length === 2")
    text = browser.evaluate("document.querySelector('[data-clear-filter=\"y\"]').textContent")
    low, high = (float(v) for v in re.findall(r"[-\d.]+(?:e-?\d+)?", text.split(" in ")[1]))
    assert low == pytest.approx(0.2, abs=0.01) and high == pytest.approx(0.6, abs=0.01)
    both = [p for p in inside if low <= p[1] <= high]
    assert 0 < len(both) < len(inside)
    assert browser.wait_for(f"{TOTAL} === '{len(both)}' && {TOTAL}") == str(len(both))
    assert all(low <= row["y"] <= high for row in table_params(browser))
    assert browser.evaluate(f"{PARALLEL}.dataset.passing") == str(len(both))
    tab(browser, "slices")
    note = browser.evaluate("document.querySelector('[data-params-note]').textContent")
    assert f"Filtered: {len(both)} of 30 complete trials pass" in note

    # The score's range; clearing a chip drops its filter.
    browser.evaluate("document.querySelector('[data-clear-filter=\"x\"]').click()")
    only_y = [p for p in points if low <= p[1] <= high]
    assert browser.wait_for(f"{TOTAL} === '{len(only_y)}' && {TOTAL}") == str(len(only_y))
    browser.evaluate(
        """(() => { const form = document.querySelector('[data-range-form]');
        form.querySelector('[data-range-name]').value = ' score';
        form.querySelector('[data-range-low]').value = '1';
        form.querySelector('[data-range-high]').value = '2';
        form.requestSubmit(); })()"""
    )
    scored = [p for p in only_y if 1 <= p[0] + p[1] <= 2]
    assert browser.wait_for(f"{TOTAL} === '{len(scored)}' && {TOTAL}") == str(len(scored))
    browser.evaluate("document.querySelector('[data-clear-filter=\"y\"]').click()")
    browser.evaluate("document.querySelector('[data-clear-filter=\" score\"]').click()")
    assert browser.wait_for(f"{TOTAL} === '30' && {TOTAL}") == "30"
    assert browser.errors == []


def edf_curves(browser: Chromium, selector: str) -> list[dict[str, Any]]:
    return list(
        json.loads(browser.evaluate(f"document.querySelector('{selector}').dataset.edfCurves"))
    )


def test_the_edf_and_studies_compared_side_by_side_at_their_own_address(
    server: ServerProcess, browser: Chromium, http: httpx.Client
) -> None:
    first = box_study(http, "compare-a", [(0.1, 0.1), (0.5, 0.2), (0.3, 0.1), (0.9, 0.9)])
    second = box_study(http, "compare-b", [(0.2, 0.2), (0.1, 0.0), (0.6, 0.6)])
    third = box_study(http, "compare-c", [(0.4, 0.4)])
    open_study(browser, server, first)
    (curve,) = edf_curves(browser, "[data-edf]")
    assert curve["n"] == 4
    assert curve["steps"] == [
        [pytest.approx(v), (k + 1) / 4] for k, v in enumerate([0.2, 0.4, 0.7, 1.8])
    ]

    # From the studies list: tick two, compare them.
    browser.navigate(f"{server.url}/#/")
    browser.wait_for(f"!!document.querySelector('input[data-pick=\"{second}\"]')")
    for study_id in (second, first):
        browser.evaluate(f"document.querySelector('input[data-pick=\"{study_id}\"]').click()")
    browser.evaluate("document.querySelector('[data-compare-picked]').click()")
    ready = "document.querySelector('[data-compare]')?.dataset.ready === 'true'"
    browser.wait_for(f"location.hash === '#/compare?ids={first},{second}' && {ready}")
    lines = json.loads(
        browser.evaluate("document.querySelector('[data-compare-history]').dataset.lines")
    )
    assert [line["id"] for line in lines] == [first, second]
    best = [[n, pytest.approx(v)] for n, v in [(0, 0.2), (1, 0.7), (2, 0.7), (3, 1.8)]]
    assert lines[0]["steps"] == best
    assert [v for _, v in lines[1]["steps"]] == [pytest.approx(v) for v in (0.4, 0.4, 1.2)]
    assert [c["n"] for c in edf_curves(browser, "[data-compare-edf]")] == [4, 3]

    # Its own checkboxes add a study (a new address); Back and Forward step through them.
    browser.evaluate(
        f"document.querySelector('[data-compare] input[data-pick=\"{third}\"]').click()"
    )
    three = f"#/compare?ids={first},{second},{third}"
    count = "document.querySelectorAll('[data-compare-legend] li').length"
    browser.wait_for(f"location.hash === '{three}' && {ready} && {count} === 3")
    browser.evaluate("history.back()")
    browser.wait_for(
        f"location.hash === '#/compare?ids={first},{second}' && {ready} && {count} === 2"
    )
    browser.evaluate("history.forward()")
    browser.wait_for(f"location.hash === '{three}' && {ready} && {count} === 3")
    assert [c["n"] for c in edf_curves(browser, "[data-compare-edf]")] == [4, 3, 1]
    assert browser.errors == []


HOSTILE = "<img src=x onerror=\"document.title='owned'\"> <b>bold</b>\nline two"


def type_note(browser: Chromium, scope: str, text: str) -> None:
    browser.evaluate(f"document.querySelector('{scope} [data-note-edit]').click()")
    browser.evaluate(
        f"(() => {{ const input = document.querySelector('{scope} [data-note-input]');"
        f" input.value = {json.dumps(text)};"
        f" document.querySelector('{scope} [data-note-save]').click(); }})()"
    )


def test_notes_on_a_study_and_a_trial_are_kept_as_text_and_a_score_shows_its_spread(
    server: ServerProcess, browser: Chromium, http: httpx.Client
) -> None:
    study_id = box_study(http, "noted", [(0.2, 0.3)])
    (other,) = http.post(f"/api/v1/studies/{study_id}/ask", json={"count": 1}).json()["trials"]
    spread = {"score_std": 0.0625, "score_min": 1.5, "score_max": 1.75, "eval_episodes": 4.0}
    tell(http, other["id"], value=1.625, metrics=spread)
    open_study(browser, server, study_id)
    scope = "[data-study-note]"
    assert browser.wait_for(f"document.querySelector('{scope} [data-note-text]').textContent") == (
        "No note yet."
    )
    type_note(browser, scope, HOSTILE)
    shown = f"document.querySelector('{scope} [data-note-text]').textContent"
    assert browser.wait_for(f"{shown} !== 'No note yet.' && {shown}") == HOSTILE
    assert browser.evaluate(f"document.querySelectorAll('{scope} img, {scope} b').length") == 0
    assert browser.evaluate("document.title") != "owned"
    assert http.get(f"/api/v1/studies/{study_id}/note").json()["text"] == HOSTILE

    # Over the bound: the server's refusal (naming it) is said; the text stays typed.
    browser.evaluate(
        f"document.querySelector('{scope} [data-note-input]')?.removeAttribute('maxlength')"
    )
    type_note(browser, scope, "x" * 10_001)
    error = browser.wait_for(
        f"!document.querySelector('{scope} [data-note-error]').hidden"
        f" && document.querySelector('{scope} [data-note-error]').textContent"
    )
    assert "10000" in error
    assert http.get(f"/api/v1/studies/{study_id}/note").json()["text"] == HOSTILE

    # The spread beside the score: in the table, the best design card and the dialog.
    marks = browser.wait_for(
        "[...document.querySelectorAll('[data-trials] [data-score-spread]')]"
        ".map(m => m.textContent.trim())"
    )
    assert marks == ["± 0.0625 (4 ep.)"]  # the first trial reported no spread
    best = browser.evaluate("document.querySelector('[data-best-card] [data-score-spread]').title")
    assert best == (
        "standard deviation of the score over 4 evaluation episodes (a seed each), from 1.5 to 1.75"
    )

    # A trial's note, in its dialog.
    browser.evaluate(f"location.hash = '#/studies/{study_id}/trials/1'")
    dialog = "[data-trial-dialog]"
    browser.wait_for(f"document.querySelector('{dialog} [data-note-edit]')?.hidden === false")
    assert "± 0.0625" in browser.evaluate(
        f"document.querySelector('{dialog} [data-score-spread]').textContent"
    )
    type_note(browser, dialog, "<script>alert(1)</script> ran hot")
    text = f"document.querySelector('{dialog} [data-note-text]').textContent"
    assert browser.wait_for(f"{text}.includes('ran hot') && {text}") == (
        "<script>alert(1)</script> ran hot"
    )
    note = http.get(f"/api/v1/trials/{other['id']}/note").json()
    assert note["text"] == "<script>alert(1)</script> ran hot"
    assert http.get(f"/api/v1/studies/{study_id}/note").json()["text"] == HOSTILE
    assert browser.errors == []
