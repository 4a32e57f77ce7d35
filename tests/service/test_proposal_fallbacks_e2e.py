"""Issue 37: a fall back to Sobol points is never silent. A model-based ask that a memory
budget (or a time budget, or a fit that fails numerically) turns into Sobol points
says so in its trials' info (``degraded``), on the study's answer, in ``adclient
status`` and on /metrics; an ask whose model proposes clears the study's reason, and
the count stays. Common studies of every kind fit their model without "model failed".
Real ``adserver`` processes, SQLite and PostgreSQL."""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
import yaml

from adclient.testing.servers import ServerProcess
from adclient.testing.workers import run_adclient

pytestmark = pytest.mark.e2e

BOX = {"type": "box", "params": [{"name": f"x{i}", "low": 0.0, "high": 1.0} for i in range(2)]}


def bumps(params: dict[str, Any]) -> float:
    x = np.array([float(params[f"x{i}"]) for i in range(2)])
    return float(np.sin(6 * x[0]) + np.cos(5 * x[1]) - np.sum((x - 0.3) ** 2))


def fed(http: httpx.Client, n: int) -> int:
    """A qei study told ``n`` evaluations of ``bumps`` at random points."""
    body = {"name": f"fed-{n}", "space": BOX, "proposer": {"name": "qei", "n_initial": 4}}
    created = http.post("/api/v1/studies", json=body)
    assert created.status_code == 201, created.text
    study = int(created.json()["id"])
    rng = np.random.default_rng(n)
    known = [{"x0": float(a), "x1": float(b)} for a, b in rng.random((n, 2))]
    added = http.post(
        f"/api/v1/studies/{study}/trials",
        json=[{"params": p, "value": bumps(p)} for p in known],
    )
    assert added.status_code in (200, 201), added.text
    return study


def ask(http: httpx.Client, study: int, count: int = 1) -> list[dict[str, Any]]:
    asked = http.post(f"/api/v1/studies/{study}/ask", json={"count": count})
    assert asked.status_code == 200, asked.text
    return list(asked.json()["trials"])


def gauge(http: httpx.Client, study: int) -> float:
    wanted = f'activedesign_proposal_fallbacks{{study="{study}"}} '
    for line in http.get("/metrics").text.splitlines():
        if line.startswith(wanted):
            return float(line.split()[-1])
    raise AssertionError(f"no {wanted.strip()} on /metrics")


def status_text(server: ServerProcess, study: int) -> str:
    done = run_adclient(server, "status", str(study))
    assert done.returncode == 0, done.stderr
    return " ".join(done.stdout.replace("│", " ").split())


def test_a_memory_budget_fall_back_shows_on_the_study_status_and_metrics(
    server_factory: Callable[..., ServerProcess],
) -> None:
    """3 MB per ask: 60 observations of 2 dimensions need about 5 MB, 12 about 1 MB."""
    server = server_factory(AD_ASK_MEMORY_MB="3")
    with httpx.Client(base_url=server.url, timeout=120) as http:
        large = fed(http, 60)
        small = fed(http, 12)

        (fell,) = ask(http, large)
        assert fell["info"]["method"] == "sobol-fallback", fell["info"]
        assert fell["info"]["degraded"] is True
        assert fell["info"]["reason"].startswith("memory budget: about 5 MB")
        study = http.get(f"/api/v1/studies/{large}").json()
        assert study["proposal_fallbacks"] == 1
        assert study["proposal_fallback_reason"] == fell["info"]["reason"]
        assert gauge(http, large) == 1.0
        said = status_text(server, large)
        assert (
            "fallback the latest ask fell back to Sobol points (1 candidate so far): "
            "memory budget: about 5 MB" in said
        ), said

        two = ask(http, large, count=2)
        assert [t["info"]["degraded"] for t in two] == [True, True]
        assert http.get(f"/api/v1/studies/{large}").json()["proposal_fallbacks"] == 3
        assert gauge(http, large) == 3.0

        (model,) = ask(http, small)
        assert not model["info"]["method"].startswith("sobol"), model["info"]
        assert "degraded" not in model["info"]
        study = http.get(f"/api/v1/studies/{small}").json()
        assert (study["proposal_fallbacks"], study["proposal_fallback_reason"]) == (0, None)
        assert gauge(http, small) == 0.0
        assert "fallback" not in status_text(server, small)

    # The operator raises the budget: the next ask is the model's, the reason goes,
    # the count of what fell back stays.
    server.env["AD_ASK_MEMORY_MB"] = "256"
    server.restart()
    with httpx.Client(base_url=server.url, timeout=120) as http:
        (model,) = ask(http, large)
        assert not model["info"]["method"].startswith("sobol"), model["info"]
        study = http.get(f"/api/v1/studies/{large}").json()
        assert (study["proposal_fallbacks"], study["proposal_fallback_reason"]) == (3, None)
        assert gauge(http, large) == 3.0
        assert "fallback" not in status_text(server, large)


EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
DESIGN = yaml.safe_load((EXAMPLES / "multi-structure.yaml").read_text())["space"]
"""Several trees with catalogue parts: the structure kernel and the held-discrete search."""
TYPED = {
    "type": "box",
    "params": [
        {"name": "x", "low": 0.0, "high": 1.0},
        {"name": "n", "type": "int", "low": 1, "high": 9},
        {"name": "lr", "low": 1e-4, "high": 1e-1, "log": True},
        {"name": "c", "type": "categorical", "choices": ["a", "b", "c"]},
    ],
}


def score(vector: list[float]) -> float:
    return float(sum(math.sin(3 * v + i) for i, v in enumerate(vector)))


@pytest.mark.parametrize(
    "study",
    [
        {"space": BOX, "proposer": {"name": "qei", "n_initial": 4, "options": {}}},
        {
            "space": BOX,
            "proposer": {"name": "qei", "n_initial": 4, "options": {"acquisition": "mc"}},
        },
        {"space": TYPED, "proposer": {"name": "qei", "n_initial": 4}},
        {"space": DESIGN, "proposer": {"name": "qei", "n_initial": 4}},
        {
            "space": BOX,
            "proposer": {"name": "qei", "n_initial": 4},
            "objectives": [
                {"metric": "f", "direction": "maximize"},
                {"metric": "g", "direction": "minimize"},
            ],
        },
        {
            "space": BOX,
            "proposer": {"name": "qei", "n_initial": 4},
            "constraints": [{"metric": "g", "op": "<=", "bound": 0.5}],
        },
    ],
    ids=["box", "box-mc", "typed-box", "design", "two-objectives", "constrained"],
)
@pytest.mark.parametrize("shared_server", ["sqlite"], indirect=True)  # the model's alone
def test_common_studies_fit_their_model_without_a_fall_back(
    shared_server: ServerProcess, study: dict[str, Any]
) -> None:
    """What no model should fail on: a fall back here is a bug hidden as Sobol points."""
    body = {"name": "no-fallback", **study}
    with httpx.Client(base_url=shared_server.url, timeout=300) as http:
        created = http.post("/api/v1/studies", json=body)
        assert created.status_code == 201, created.text
        sid = int(created.json()["id"])
        infos = []
        for _ in range(5):
            for trial in ask(http, sid, count=2):
                infos.append(trial["info"])
                f = score(trial["vector"])
                metrics = {"f": f, "g": abs(math.cos(f))}
                told = http.post(
                    f"/api/v1/trials/{trial['id']}/tell", json={"value": f, "metrics": metrics}
                )
                assert told.is_success, told.text
        modelled = [info for info in infos if not info["method"].startswith("sobol-initial")]
        assert modelled, infos
        degraded = [info for info in modelled if info.get("degraded")]
        assert degraded == [], degraded
        assert http.get(f"/api/v1/studies/{sid}").json()["proposal_fallbacks"] == 0


@pytest.mark.slow
@pytest.mark.parametrize("database", ["sqlite"])
def test_a_study_of_ten_thousand_trials_gets_model_based_proposals(
    database: str, server_factory: Callable[..., ServerProcess]
) -> None:
    """With the default memory budget, where every ask used to fall back to Sobol points
    past about 3,000 observations ("memory budget: about 17567 MB ..." at 10,000)."""
    server = server_factory()
    dim, n = 6, 10_000
    space = {
        "type": "box",
        "params": [{"name": f"x{i}", "low": 0.0, "high": 1.0} for i in range(dim)],
    }
    rng = np.random.default_rng(37)
    unit = rng.random((n, dim))
    values = -np.sum((unit - 0.3) ** 2, axis=1) + 0.2 * np.sin(5.0 * unit.sum(axis=1))
    with httpx.Client(base_url=server.url, timeout=300) as http:
        body = {"name": "ten-thousand", "space": space, "proposer": {"name": "qei"}}
        study = http.post("/api/v1/studies", json=body).json()["id"]
        known = [
            {"params": {f"x{i}": float(v) for i, v in enumerate(row)}, "value": float(value)}
            for row, value in zip(unit, values, strict=True)
        ]
        for start in range(0, n, 2_000):  # under the 1 MB body limit
            chunk = known[start : start + 2_000]
            added = http.post(f"/api/v1/studies/{study}/trials", json=chunk)
            assert added.status_code in (200, 201), added.text[:500]
        trials = ask(http, study, count=2)
        for trial in trials:
            info = trial["info"]
            assert not info["method"].startswith("sobol"), info
            assert info["n_observed"] == n, info
            # a subset of the most the default budget (1024 MB) holds, at most 2048 on cpu
            assert (info["model"], info["n_train"]) == ("subset", 2048), info
        answer = http.get(f"/api/v1/studies/{study}").json()
        assert (answer["proposal_fallbacks"], answer["n_trials"]) == (0, n + 2)
