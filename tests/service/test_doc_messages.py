"""Every refusal docs/study-file.md quotes is what the server says today: each quote is
triggered against a real server and found, word for word, in the answer's problems
(issue 39: the docs listed built-in tasks the server no longer named). A quote added to
the page's list without a case here fails the test, so the list cannot drift again."""

from __future__ import annotations

import copy
import re
from pathlib import Path
from typing import Any

import httpx
import pytest
import yaml

from adclient.testing.servers import SDK_HEADERS, ServerProcess

pytestmark = pytest.mark.e2e

ROOT = Path(__file__).resolve().parents[2]
PAGE = ROOT / "docs" / "study-file.md"
STAND_UP = yaml.safe_load((ROOT / "examples" / "stand-up.yaml").read_text())


def stand_up(change: Any) -> dict[str, Any]:
    """examples/stand-up.yaml with ``change(body)`` applied."""
    body = copy.deepcopy(STAND_UP)
    change(body)
    return body


def _set(path: str, value: Any) -> Any:
    def change(body: dict[str, Any]) -> None:
        *parents, last = path.split(".")
        node = body
        for key in parents:
            node = node[int(key)] if isinstance(node, list) else node[key]
        if value is _DELETE:
            del node[last]
        elif isinstance(node, list):
            node[int(last)] = value
        else:
            node[last] = value

    return change


_DELETE = object()

CASES: dict[str, dict[str, Any]] = {
    "space.design.parts.link.length: a searched spec is {low, high}: bound low (0.6) must be "
    "< high (0.25)": stand_up(_set("space.parts.link.length", {"low": 0.6, "high": 0.25})),
    "body: max_trials is required for a study with a task (a managed study)": stand_up(
        _set("max_trials", _DELETE)
    ),
    "space: Unable to extract tag using discriminator 'type'": stand_up(
        _set("space.type", _DELETE)
    ),
    "proposer.n_initial: Input should be greater than or equal to 1": stand_up(
        _set("proposer.n_initial", 0)
    ),
    "space.design: structures[0][1]: unknown instance 'd' (instances: a, b, c)": stand_up(
        _set("space.structures", [[["a", "b"], ["b", "d"]]])
    ),
    "space.design.instances.0: instance 'a': overrides has unknown key 'colour' (expected one "
    "of length, radius, mass, density)": stand_up(
        _set("space.instances.0", {"name": "a", "part": "link", "overrides": {"colour": 1}})
    ),
    "space.design.joint: joint: joint limit lower (2.0) can exceed upper (1.5707963267948966); "
    "the largest lower must be <= the smallest upper": stand_up(_set("space.joint.lower", 2.0)),
    "space.design.joint.effort: a searched spec is {low, high}: log: a log scale needs low > 0, "
    "got 0.0": stand_up(_set("space.joint.effort", {"low": 0.0, "high": 5.0, "log": True})),
    "proposer.name: unknown proposer 'cmaes'; choose one of nelder-mead, qei, random, sobol, "
    "tpe": stand_up(_set("proposer.name", "cmaes")),
    "proposer.options.kernel: Input should be 'rbf' or 'matern'": stand_up(
        _set("proposer.options", {"kernel": "periodic"})
    ),
    "proposer.options.colour: unknown option of qei (its options: noise, kernel, ...)": stand_up(
        _set("proposer.options", {"colour": "red"})
    ),
    "task.name: unknown task 'stand_up'; the installed tasks are carry-payload, "
    "diagonal-gesture, lift-highest, reach-workspace, stand-up, track-velocity, walk-forward "
    "(a task that workers of your own serve, such as adworker --function, needs external: "
    "true)": stand_up(_set("task.name", "stand_up")),
    "task.options: frame_skip: Input should be greater than or equal to 1": stand_up(
        _set("task.options", {"frame_skip": 0})
    ),
    "body: task 'lift-highest' builds a robot: it needs a design space (space.type: design) "
    "or a template (space.type: template), not 'box'": stand_up(
        lambda body: body.update(
            task={"name": "lift-highest"},
            space={"type": "box", "params": [{"name": "x", "low": 0, "high": 1}]},
        )
    ),
}


def _example(name: str) -> dict[str, Any]:
    return yaml.safe_load((ROOT / "examples" / name).read_text())


def catalogue_override() -> dict[str, Any]:
    body = _example("catalogue-arm.yaml")
    body["space"]["instances"][1]["joint_overrides"] = {"effort": 5.0}
    return body


def misspelt_template() -> dict[str, Any]:
    """examples/template-arm.yaml, its template's line 50 naming ``forarm``."""
    body = _example("template-arm.yaml")
    lines = (ROOT / "examples" / body["space"]["template"]).read_text().splitlines()
    assert "${fore}" in lines[49]
    lines[49] = lines[49].replace("${fore}", "${forarm}")
    body["space"]["template"] = "\n".join(lines)
    return body


PROSE = {
    "space.template: template: line 50: NameError: name 'forarm' is not defined when "
    "evaluating expression 'forarm'": misspelt_template(),
    "instances[1] ('b'): joint_overrides effort: the component chosen from catalogue "
    "'servos' sets them": catalogue_override(),
}
"""Refusals quoted in the page's prose, by what triggers each."""


def quoted_list() -> list[str]:
    """The bullets of the page's "Other messages, as the server words them" list."""
    text = PAGE.read_text()
    start = text.index("Other messages, as the server words them:")
    block = text[start:].split("\n\n")[1]
    return re.findall(r"^- `([^`]+)`", block, re.M)


def found(quote: str, problems: list[str]) -> bool:
    """The quote is one of the problems; ``...`` in it stands for any text."""
    pattern = ".*".join(re.escape(part) for part in quote.split("..."))
    return any(re.fullmatch(pattern, problem) for problem in problems)


def test_the_page_quotes_nothing_untested() -> None:
    quotes = quoted_list()
    assert len(quotes) >= 10
    assert set(quotes) <= set(CASES), set(quotes) - set(CASES)
    page = re.sub(r"\s+", " ", PAGE.read_text())
    for quote in [*CASES, *PROSE]:  # and each case is still quoted on the page
        assert quote in page, quote


@pytest.mark.parametrize("shared_server", ["sqlite"], indirect=True)  # the words, not the store
def test_each_quoted_refusal_is_what_the_server_says(shared_server: ServerProcess) -> None:
    with httpx.Client(base_url=shared_server.url, headers=SDK_HEADERS, timeout=60) as http:
        for quote, body in {**CASES, **PROSE}.items():
            answer = http.post("/api/v1/studies", json=body)
            assert answer.status_code == 422, (quote, answer.text)
            problems = answer.json()["problems"]
            assert any(quote in problem for problem in problems) or found(quote, problems), (
                quote,
                problems,
            )
        assert http.get("/api/v1/studies").json() == []  # nothing was stored
