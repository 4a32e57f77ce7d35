"""Several objectives and outcome constraints (issue 17) against a real server, on SQLite
and PostgreSQL: tells with the wrong number of values store nothing, the Pareto endpoint
agrees with a brute-force front, constraints mark trials infeasible and keep them out of
the best and the front, and objectives read from told metrics."""

from __future__ import annotations

import random
from collections.abc import Callable
from typing import Any

import httpx
import pytest

from adclient.testing.servers import ServerProcess
from tests.service.fronts import brute_front

pytestmark = [pytest.mark.e2e, pytest.mark.xdist_group("multiobjective")]
"""One xdist worker runs the module: the tests on ``shared_server`` share its two servers."""

SPACE = {"type": "box", "params": [{"name": "x", "low": 0.0, "high": 1.0}]}


def create(http: httpx.Client, **fields: Any) -> dict[str, Any]:
    body = {"name": "mo", "space": SPACE, "proposer": {"name": "random", "seed": 1}} | fields
    created = http.post("/api/v1/studies", json=body)
    assert created.status_code == 201, created.text
    return dict(created.json())


def ask(http: httpx.Client, sid: int, count: int = 1) -> list[dict[str, Any]]:
    asked = http.post(f"/api/v1/studies/{sid}/ask", json={"count": count})
    assert asked.status_code == 200, asked.text
    return list(asked.json()["trials"])


def tell(http: httpx.Client, trial_id: int, **body: Any) -> httpx.Response:
    return http.post(f"/api/v1/trials/{trial_id}/tell", json=body)


def test_values_pareto_and_best(shared_server: ServerProcess) -> None:
    rng = random.Random(7)
    with httpx.Client(base_url=shared_server.url, timeout=30, verify=False) as http:
        study = create(
            http,
            directions=["maximize", "minimize", "maximize"],
            objective_names=["score", "mass", "speed"],
        )
        sid = study["id"]
        assert study["directions"] == ["maximize", "minimize", "maximize"]
        assert study["objective_names"] == ["score", "mass", "speed"]
        assert study["direction"] == "maximize"
        trials = ask(http, sid, 40)

        # Wrong counts and shapes: 422 naming the problem, the trial still running.
        first = trials[0]["id"]
        for body, words in [
            ({"value": 1.0}, "3 objectives"),
            ({"values": [1.0, 2.0]}, "not 2"),
            ({"values": [1.0, 2.0, 3.0, 4.0]}, "not 4"),
            ({"values": [1.0, "NaN", 2.0]}, "values.1: Input should be a valid number"),
            ({"values": [1.0, 2.0, 3.0], "value": 1.0}, "not both"),
            ({"state": "failed", "values": [1.0, 2.0, 3.0]}, "no values"),
        ]:
            refused = tell(http, first, **body)
            assert refused.status_code == 422, (body, refused.text)
            assert words in refused.text, (body, refused.text)
        assert http.get(f"/api/v1/trials/{first}").json()["state"] == "running"
        assert http.get(f"/api/v1/studies/{sid}").json()["n_complete"] == 0

        told: dict[int, list[float]] = {}
        for index, trial in enumerate(trials):
            values = [float(rng.randint(0, 6)) for _ in range(3)]
            if index == 5:
                values = list(told[trials[2]["id"]])  # an equal point: both on the front
            answer = tell(http, trial["id"], values=values)
            assert answer.status_code == 200, answer.text
            assert answer.json()["values"] == values
            assert answer.json()["value"] is None
            told[trial["id"]] = values

        # An identical repeat is harmless; a contradicting one is a conflict.
        again = tell(http, first, values=told[first])
        assert again.status_code == 200, again.text
        other = [v + 1 for v in told[first]]
        conflict = tell(http, first, values=other)
        assert conflict.status_code == 409, conflict.text

        front = http.get(f"/api/v1/studies/{sid}/pareto")
        assert front.status_code == 200, front.text
        expected = brute_front(told, [1.0, -1.0, 1.0])
        assert {t["id"] for t in front.json()} == expected
        assert (trials[2]["id"] in expected) == (trials[5]["id"] in expected)  # equal points
        assert [t["number"] for t in front.json()] == sorted(t["number"] for t in front.json())

        best = http.get(f"/api/v1/studies/{sid}/best")
        assert best.status_code == 409, best.text
        assert f"/api/v1/studies/{sid}/pareto" in best.json()["detail"]
        info = http.get(f"/api/v1/studies/{sid}").json()
        assert info["n_complete"] == 40
        assert info["state"] == "running"
        assert info["best_value"] is None and info["best_trial_id"] is None


def test_constraints_mark_infeasible_trials(shared_server: ServerProcess) -> None:
    with httpx.Client(base_url=shared_server.url, timeout=30, verify=False) as http:
        sid = create(
            http,
            direction="maximize",
            constraints=[
                {"metric": "mass", "op": "<=", "bound": 2.0},
                {"metric": "value", "op": ">=", "bound": -5.0},
            ],
        )["id"]
        trials = ask(http, sid, 4)
        missing = tell(http, trials[0]["id"], value=3.0)
        assert missing.status_code == 422, missing.text
        assert "mass" in missing.json()["detail"]

        outcomes = [(9.0, 3.0), (4.0, 2.0), (1.0, 0.5), (-7.0, 0.1)]
        answers = []
        for trial, (value, mass) in zip(trials, outcomes, strict=True):
            answer = tell(http, trial["id"], value=value, metrics={"mass": mass})
            assert answer.status_code == 200, answer.text
            answers.append(answer.json())
        assert [a["feasible"] for a in answers] == [False, True, True, False]
        assert [a["value"] for a in answers] == [9.0, 4.0, 1.0, -7.0]

        best = http.get(f"/api/v1/studies/{sid}/best").json()
        assert best["id"] == trials[1]["id"]  # 9.0 breaks mass <= 2
        front = http.get(f"/api/v1/studies/{sid}/pareto").json()
        assert [t["id"] for t in front] == [trials[1]["id"]]
        infeasible = http.get(f"/api/v1/studies/{sid}/trials").json()
        assert {t["number"]: t["feasible"] for t in infeasible} == {
            0: False,
            1: True,
            2: True,
            3: False,
        }


def test_objectives_read_from_told_metrics(shared_server: ServerProcess) -> None:
    """A managed study's workers tell the task score as the value and its metrics
    beside it; ``objectives`` picks the objectives from them."""
    with httpx.Client(base_url=shared_server.url, timeout=30, verify=False) as http:
        study = create(
            http,
            objectives=[
                {"metric": "score", "direction": "maximize"},
                {"metric": "mass", "direction": "minimize"},
            ],
            reference_point=[0.0, 10.0],
        )
        assert study["objectives"] == [
            {"metric": "score", "direction": "maximize"},
            {"metric": "mass", "direction": "minimize"},
        ]
        assert study["objective_names"] == ["score", "mass"]
        assert study["reference_point"] == [0.0, 10.0]
        trial = ask(http, study["id"])[0]
        no_mass = tell(http, trial["id"], value=0.5)
        assert no_mass.status_code == 422 and "'mass'" in no_mass.text, no_mass.text
        told = tell(http, trial["id"], value=0.5, metrics={"mass": 1.5, "energy": 3.0})
        assert told.status_code == 200, told.text
        assert told.json()["values"] == [0.5, 1.5]
        repeat = tell(http, trial["id"], value=0.5, metrics={"mass": 1.5, "energy": 3.0})
        assert repeat.status_code == 200, repeat.text
        trial = ask(http, study["id"])[0]
        direct = tell(http, trial["id"], values=[0.7, 2.5])
        assert direct.status_code == 200 and direct.json()["values"] == [0.7, 2.5], direct.text


def test_warm_start_with_values(shared_server: ServerProcess) -> None:
    with httpx.Client(base_url=shared_server.url, timeout=30, verify=False) as http:
        sid = create(http, directions=["minimize", "minimize"])["id"]
        bad = http.post(
            f"/api/v1/studies/{sid}/trials",
            json=[{"params": {"x": 0.1}, "values": [1, 2]}, {"params": {"x": 0.2}, "value": 3}],
        )
        assert bad.status_code == 422, bad.text
        assert "trials[1].values" in bad.text
        assert http.get(f"/api/v1/studies/{sid}").json()["n_trials"] == 0
        added = http.post(
            f"/api/v1/studies/{sid}/trials",
            json=[
                {"params": {"x": 0.1}, "values": [1, 2]},
                {"params": {"x": 0.2}, "values": [2, 1]},
                {"params": {"x": 0.3}, "values": [3, 3]},
            ],
        )
        assert added.status_code == 201, added.text
        front = http.get(f"/api/v1/studies/{sid}/pareto").json()
        assert sorted(t["params"]["x"] for t in front) == [0.1, 0.2]
        assert http.get(f"/api/v1/studies/{sid}").json()["n_complete"] == 3


@pytest.mark.parametrize(
    ("fields", "words"),
    [
        ({"direction": "minimize", "directions": ["maximize", "minimize"]}, "disagree"),
        (
            {"directions": ["maximize"], "objectives": [{"metric": "mass"}]},
            "give one of them",
        ),
        ({"directions": ["maximize"] * 5}, "at most 4"),
        ({"directions": ["maximize", "sideways"]}, "directions.1"),
        ({"directions": ["maximize", "minimize"], "objective_names": ["a"]}, "1 names"),
        ({"directions": ["maximize", "minimize"], "objective_names": ["a", "a"]}, "own name"),
        ({"objective_names": ["a"]}, "directions"),
        ({"directions": ["maximize", "minimize"], "reference_point": [1.0]}, "1 numbers"),
        ({"reference_point": [1.0]}, "several objectives"),
        (
            {
                "directions": ["maximize", "minimize"],
                "pruner": {"name": "asha", "options": {"min_resource": 1}},
            },
            "pruner none",
        ),
        ({"directions": ["maximize", "minimize"], "proposer": {"name": "nelder-mead"}}, "nelder"),
        ({"constraints": [{"metric": "mass", "op": "<", "bound": 1}]}, "op"),
        ({"constraints": [{"metric": "mass", "op": "<=", "bound": "inf"}]}, "bound"),
        (
            {"constraints": [{"metric": "mass", "op": "<=", "bound": 1}]}
            | {"proposer": {"name": "nelder-mead"}},
            "constraints",
        ),
    ],
)
def test_bad_objective_settings_store_nothing(
    shared_server: ServerProcess, fields: dict[str, Any], words: str
) -> None:
    with httpx.Client(base_url=shared_server.url, timeout=30, verify=False) as http:
        before = len(http.get("/api/v1/studies").json())
        body = {"name": "bad", "space": SPACE, "proposer": {"name": "random"}} | fields
        refused = http.post("/api/v1/studies", json=body)
        assert refused.status_code == 422, refused.text
        assert words in refused.text, refused.text
        assert len(http.get("/api/v1/studies").json()) == before


@pytest.mark.slow
def test_qei_proposes_for_several_objectives_under_a_constraint(
    server_factory: Callable[..., ServerProcess],
) -> None:
    """The default proposer past its space-filling start: a warm-started study of two
    objectives and a constraint asks through analytic LogEHVI, the told outcomes in the model.
    (A time budget far past any machine's fit: the model path is what is checked.)"""
    server = server_factory(AD_ASK_SECONDS="600")
    with httpx.Client(base_url=server.url, timeout=900, verify=False) as http:
        sid = create(
            http,
            directions=["maximize", "minimize"],
            constraints=[{"metric": "cost", "op": "<=", "bound": 0.8}],
            space={
                "type": "box",
                "params": [
                    {"name": "x", "low": 0.0, "high": 1.0},
                    {"name": "y", "low": 0, "high": 1},
                ],
            },
            proposer={"name": "qei", "seed": 2, "n_initial": 4},
        )["id"]
        warm = [
            {
                "params": {"x": x, "y": y},
                "values": [x, 1 - x * x + 0.1 * y],
                "metrics": {"cost": x + y},
            }
            for x, y in [(0.1, 0.2), (0.4, 0.1), (0.7, 0.6), (0.9, 0.05), (0.3, 0.9), (0.5, 0.2)]
        ]
        added = http.post(f"/api/v1/studies/{sid}/trials", json=warm)
        assert added.status_code == 201, added.text
        assert [t["feasible"] for t in added.json()] == [True, True, False, False, False, True]
        asked = ask(http, sid, 2)
        assert len(asked) == 2
        for trial in asked:
            info = trial["info"]
            assert info["acquisition"] == "LogEHVI", info
            assert info["method"] in ("LogEHVI", "LogEHVI-believer"), info
            assert (info["n_objectives"], info["n_constraints"], info["n_feasible"]) == (2, 1, 3)
            # the reference point in each objective's own direction: past the worst
            # feasible value of each, below for the maximised, above for the minimised
            feasible = [w["values"] for w, f in zip(warm, [1, 1, 0, 0, 0, 1], strict=True) if f]
            assert info["ref_point"][0] < min(v[0] for v in feasible), info
            assert info["ref_point"][1] > max(v[1] for v in feasible), info
            assert 0 <= trial["params"]["x"] <= 1 and 0 <= trial["params"]["y"] <= 1
