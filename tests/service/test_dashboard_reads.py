"""What the dashboard's pages read and the browser tests see drawn, on SQLite and
PostgreSQL: chart columns of several objectives under a constraint (values, feasibility,
a delta), of a constrained single objective, of int and categorical params and of a
design study's spec names, and a study's learning curves.

The browser tests of those pages (test_pareto_browser, test_dashboard_importance_browser,
test_curves_browser, test_dashboard_browser, test_dashboard_workers_browser) run on
SQLite alone: a page sees only these answers, so what the database changes is asserted
here, in-process, on both."""

from __future__ import annotations

import random
from datetime import timedelta
from typing import Any

import yaml
from fastapi.testclient import TestClient

from adservice.db import Database
from adservice.models import WorkerRow
from adservice.settings import Settings
from tests.service.dashboard_pages import EXAMPLES, seed_curves
from tests.service.fronts import brute_front

SPACE = {"type": "box", "params": [{"name": "x", "low": 0.0, "high": 1.0}]}


def create(api: TestClient, **fields: Any) -> int:
    body = {"name": "reads", "space": SPACE, "proposer": {"name": "random", "seed": 5}} | fields
    created = api.post("/api/v1/studies", json=body)
    assert created.status_code == 201, created.text
    return int(created.json()["id"])


def ask(api: TestClient, study_id: int, count: int) -> list[dict[str, Any]]:
    asked = api.post(f"/api/v1/studies/{study_id}/ask", json={"count": count})
    assert asked.status_code == 200, asked.text
    return list(asked.json()["trials"])


def tell(api: TestClient, trial_id: int, **body: Any) -> None:
    told = api.post(f"/api/v1/trials/{trial_id}/tell", json=body)
    assert told.status_code == 200, told.text


def series(api: TestClient, study_id: int, **params: Any) -> dict[str, Any]:
    answer = api.get(f"/api/v1/dashboard/studies/{study_id}/series", params=params)
    assert answer.status_code == 200, answer.text
    return dict(answer.json())


def test_two_objectives_under_a_constraint_give_values_feasibility_and_the_front(
    api: TestClient,
) -> None:
    """The Pareto chart's columns (test_pareto_browser): each trial's values and whether
    it meets ``mass <= 3``, None for a failed or running one; the front among the
    feasible; a delta with the running trial told."""
    study_id = create(
        api,
        directions=["maximize", "minimize"],
        objective_names=["speed", "mass"],
        constraints=[{"metric": "mass", "op": "<=", "bound": 3.0}],
    )
    trials = ask(api, study_id, 12)
    rng = random.Random(17)
    told: dict[int, list[float]] = {}
    for trial in trials[:10]:
        values = [round(rng.uniform(0, 10), 3), round(rng.uniform(0.5, 5), 3)]
        tell(api, trial["id"], values=values)
        told[trial["number"]] = values
    tell(api, trials[10]["id"], state="failed")
    feasible = {n: v for n, v in told.items() if v[1] <= 3.0}
    assert 0 < len(feasible) < len(told)

    columns = series(api, study_id)
    assert columns["value"] == [None] * 12
    for number, values in told.items():
        assert columns["values"][number] == values
        assert columns["feasible"][number] is (values[1] <= 3.0)
    assert columns["values"][10:] == [None, None] and columns["feasible"][10:] == [None, None]
    pareto = api.get(f"/api/v1/studies/{study_id}/pareto").json()
    assert {t["number"] for t in pareto} == brute_front(feasible, [1.0, -1.0])

    tell(api, trials[11]["id"], values=[20.0, 0.25])
    delta = series(api, study_id, after=12, numbers="11")
    assert delta["number"] == [11]
    assert delta["values"] == [[20.0, 0.25]] and delta["feasible"] == [True]
    assert [t["number"] for t in api.get(f"/api/v1/studies/{study_id}/pareto").json()] == [11]


def test_three_objectives_and_a_constrained_single_objective(api: TestClient) -> None:
    """Three objectives: a value per objective in each trial's column. One objective under
    a constraint: no values column, a feasibility column, the best feasible best."""
    three = create(api, directions=["maximize", "minimize", "maximize"])
    rng = random.Random(4)
    told = []
    for trial in ask(api, three, 5):
        told.append([round(rng.uniform(-5, 5), 3) for _ in range(3)])
        tell(api, trial["id"], values=told[-1])
    assert series(api, three)["values"] == told

    one = create(api, constraints=[{"metric": "mass", "op": "<=", "bound": 1.0}])
    for i, trial in enumerate(ask(api, one, 4)):
        tell(api, trial["id"], value=float(i), metrics={"mass": 0.5 + i / 3})
    columns = series(api, one)
    assert columns["values"] is None
    assert columns["value"] == [0.0, 1.0, 2.0, 3.0]
    assert columns["feasible"] == [True, True, False, False]
    assert api.get(f"/api/v1/studies/{one}/best").json()["number"] == 1


def test_int_and_categorical_columns_keep_their_types(api: TestClient) -> None:
    """The parallel coordinates and slices (test_dashboard_browser): an int param's column
    holds ints, a categorical one's its choices, as the trials have them."""
    space = {
        "type": "box",
        "params": [
            {"name": "width", "type": "int", "low": 1, "high": 64, "log": True},
            {"name": "activation", "type": "categorical", "choices": ["relu", "tanh", "gelu"]},
        ],
    }
    study_id = create(api, space=space)
    trials = ask(api, study_id, 6)
    for trial in trials:
        tell(api, trial["id"], value=float(trial["params"]["width"]))
    columns = series(api, study_id)
    assert columns["params"]["width"] == [t["params"]["width"] for t in trials]
    assert all(type(width) is int for width in columns["params"]["width"])
    assert columns["params"]["activation"] == [t["params"]["activation"] for t in trials]


def test_a_design_studys_columns_are_its_spec_names(api: TestClient) -> None:
    """The importance and contour panels (test_dashboard_importance_browser) name a
    design study's params as its columns do: spec names, fixed ones included, each
    column the trials' values."""
    body = yaml.safe_load((EXAMPLES / "stand-up.yaml").read_text())
    body.pop("task")
    body.update(name="design-columns", proposer={"name": "random", "seed": 2})
    study_id = int(api.post("/api/v1/studies", json=body).raise_for_status().json()["id"])
    trials = ask(api, study_id, 4)
    for trial in trials:
        tell(api, trial["id"], value=trial["params"]["b.length"])
    columns = series(api, study_id)["params"]
    assert {"b.length", "a.radius"} <= set(columns) <= set(trials[0]["params"])
    for name, column in columns.items():
        assert column == [t["params"][name] for t in trials], name
    assert len(set(columns["b.length"])) > 1 and set(columns["a.radius"]) == {0.04}


def test_learning_curves_per_reporting_trial_in_order_of_steps(api: TestClient) -> None:
    """The curves chart's read (test_curves_browser, which draws this study): a curve per
    trial that reported, its steps in order whatever order they came in; the latest
    ``limit`` curves, and whether there are more; a limit of 0 is refused."""
    study_id, (silent, done, pruned, running) = seed_curves(api)
    url = f"/api/v1/dashboard/studies/{study_id}/curves"
    curves = api.get(url).json()
    assert [(c["trial_id"], c["state"]) for c in curves["curves"]] == [
        (done, "complete"),
        (pruned, "pruned"),
        (running, "running"),
    ]
    assert silent not in {c["trial_id"] for c in curves["curves"]}
    assert curves["curves"][0]["steps"] == [100, 200, 300]
    assert curves["curves"][0]["values"] == [0.1, 0.3, 0.5]
    assert curves["more"] is False
    latest = api.get(url, params={"limit": 2}).json()
    assert [c["trial_id"] for c in latest["curves"]] == [pruned, running] and latest["more"]
    assert api.get(url, params={"limit": 0}).status_code == 422


def test_the_trials_table_reads_who_handed_a_trial_over_and_its_transfer_source(
    api: TestClient,
) -> None:
    """The trials table's marks (test_enqueue_browser, test_transfer_browser): an added
    or enqueued trial's source, a warm-started trial's source trial, as listed."""
    study_id = create(api, name="handed")
    url = f"/api/v1/studies/{study_id}/trials"
    added = api.post(url, json={"params": {"x": 0.25}, "value": 1.0}).json()
    queued = api.post(url, json={"params": {"x": 0.75}}).json()
    asked = ask(api, study_id, 2)
    listed = {t["id"]: t["info"].get("source") for t in api.get(url).json()}
    assert listed == {added["id"]: "added", queued["id"]: "enqueued", asked[1]["id"]: None}

    task = {"name": "mine", "external": True, "transfer": "nearest"}
    warm = create(api, name="warm", task=task, max_trials=2)
    first, second = (
        api.post("/api/v1/jobs/lease", json={"worker_id": "w"}).json() for _ in range(2)
    )
    for job, source in ((first, None), (second, first["trial_id"])):
        put = api.put(
            f"/api/v1/trials/{job['trial_id']}/artifacts/checkpoint.zip",
            params={"worker_id": "w"},
            content=b"PK",
        )
        assert put.status_code == 201, put.text
        tell(api, job["trial_id"], value=1.0, worker_id="w", transfer_from=source)
    listed = api.get(f"/api/v1/studies/{warm}/trials").json()
    assert {t["id"]: t["info"].get("transfer_from") for t in listed} == {
        first["trial_id"]: None,
        second["trial_id"]: first["trial_id"],
    }


def test_workers_not_heard_from_lately_are_gone(api: TestClient, settings: Settings) -> None:
    """The workers tables' state (test_dashboard_workers_browser draws it): gone past the
    server's 90 s without contact, whatever the worker held; idle or working before."""
    managed = {"task": {"name": "reads-sim", "external": True}, "max_trials": 5}
    study = create(api, name="workers", **managed)
    for worker, tasks in (("left", ["reads-sim"]), ("busy", ["reads-sim"]), ("idle", ["x"])):
        leased = api.post("/api/v1/jobs/lease", json={"worker_id": worker, "tasks": tasks})
        assert leased.status_code == (204 if worker == "idle" else 200), leased.text
    db = Database(settings.database_url)
    try:
        with db.write() as session:
            left = session.get(WorkerRow, "left")
            assert left is not None
            left.last_seen_at -= timedelta(seconds=91)
    finally:
        db.dispose()
    listed = {w["worker_id"]: w["state"] for w in api.get("/api/v1/workers").json()}
    assert listed == {"left": "gone", "busy": "working", "idle": "idle"}
    of_study = api.get(f"/api/v1/studies/{study}/workers").json()
    assert {w["worker_id"]: w["state"] for w in of_study} == {"left": "gone", "busy": "working"}
