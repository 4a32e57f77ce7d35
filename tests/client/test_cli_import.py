"""``adclient import`` and ``enqueue`` against a real ``adserver`` (issue 16): an export
imported again gives a study with the same best trial; a CSV goes into a study of the
same space; the SDK's ``enqueue_trial`` and ``add_trial`` do what Optuna's do."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from adclient import Client
from adclient.errors import Invalid
from adclient.importing import ImportFileError, read_import
from adclient.testing.servers import ServerProcess
from tests.client.cli_harness import failed_with, ok, run

SPACE = {
    "type": "box",
    "params": [
        {"name": "x", "low": 0.001, "high": 10.0, "log": True},
        {"name": "n", "type": "int", "low": 1, "high": 9},
        {"name": "c", "type": "categorical", "choices": ["a", "b", "z"]},
    ],
}


def objective(params: dict) -> float:
    return -((params["x"] - 2) ** 2) - params["n"] + (1.0 if params["c"] == "z" else 0.0)


def evaluated_study(client: Client, name: str) -> int:
    """Seven complete trials, one failed, one left running."""
    study = client.create_study(name=name, space=SPACE, proposer={"name": "random", "seed": 4})
    for trial in study.ask(count=9)[:8]:
        if trial.number == 5:
            study.tell(trial, state="failed", message="fell over")
        else:
            study.tell(trial, objective(trial.params), metrics={"steps": 10.0})
    return study.id


def test_an_export_imported_again_has_the_same_best_trial(
    server: ServerProcess, client: Client, tmp_path: Path
) -> None:
    source = evaluated_study(client, "source")
    exported = tmp_path / "study.json"
    ok(run(server.url, "export", str(source), "--format", "json", "--output", str(exported)))
    done = ok(run(server.url, "import", str(exported), "--name", "copy"))
    assert "9 trials imported" in done.stdout
    copy = int(done.stderr.split("study ")[1].split()[0])
    original, imported = client.study_info(source), client.study_info(copy)
    assert imported.name == "copy" and imported.space == original.space
    assert (imported.n_complete, imported.n_failed, imported.n_queued) == (7, 1, 1)
    assert imported.best_value == original.best_value
    assert client.best_trial(copy).params == client.best_trial(source).params  # type: ignore[union-attr]
    assert client.best_trial(copy).metrics == {"steps": 10.0}  # type: ignore[union-attr]
    # The running trial came in queued: the next ask evaluates it again.
    again = client.ask(copy)[0]
    running = next(t for t in client.trials(source) if t.state == "running")
    assert again.params == running.params and again.info["source"] == "enqueued"
    skipped = ok(run(server.url, "import", str(exported), "--skip-unfinished"))
    assert "8 trials imported, 1 unfinished left out" in skipped.stdout


def test_a_csv_goes_into_a_study_of_its_space(
    server: ServerProcess, client: Client, tmp_path: Path
) -> None:
    source = evaluated_study(client, "csv-source")
    table = tmp_path / "trials.csv"
    ok(run(server.url, "export", str(source), "--output", str(table)))
    target = client.create_study(name="csv-target", space=SPACE).id
    ok(run(server.url, "import", str(table), "--study", str(target)))
    assert client.study_info(target).best_value == client.study_info(source).best_value
    best = client.best_trial(target)
    assert best is not None and isinstance(best.params["n"], int)
    # A plain CSV of param columns and a value column, as a spreadsheet would have it.
    plain = tmp_path / "plain.csv"
    plain.write_text("x,n,c,value\n2.0,1,z,0.0\n0.5,4,a,\n")
    before = client.study_info(target).n_trials
    ok(run(server.url, "import", str(plain), "--study", str(target)))
    after = client.study_info(target)
    assert after.n_trials == before + 2 and after.best_value == 0.0
    bad = tmp_path / "bad.csv"
    bad.write_text("x,n,c,value\n2.0,1,z,1.0\n0.5,4,zz,2.0\n")
    failed_with(run(server.url, "import", str(bad), "--study", str(target)), "line 3, c")
    assert client.study_info(target).n_trials == after.n_trials  # nothing from a bad file
    outside = tmp_path / "outside.csv"
    outside.write_text("x,n,c,value\n20.0,1,z,1.0\n")
    failed_with(
        run(server.url, "import", str(outside), "--study", str(target)),
        "param 'x': 20.0 is outside",
    )
    failed_with(run(server.url, "import", str(plain)), "give --study ID", code=2)


def test_a_study_of_two_objectives_round_trips_with_its_front(
    server: ServerProcess, client: Client, tmp_path: Path
) -> None:
    """Issue 17: the export's values, constraints and feasibility come back, by JSON into
    a new study of the same objectives and by CSV (``values_<i>``) into an existing one."""
    study = client.create_study(
        name="two",
        space=SPACE,
        directions=["maximize", "minimize"],
        objective_names=["score", "mass"],
        constraints=[{"metric": "cost", "op": "<=", "bound": 5.0}],
        proposer={"name": "random", "seed": 2},
    )
    for trial in study.ask(count=8):
        p = trial.params
        study.tell(trial, [objective(p), p["x"]], metrics={"cost": float(p["n"])})
    front = {tuple(t.values or []) for t in study.best_trials}
    assert front and all(t.feasible for t in study.best_trials)
    exported = tmp_path / "two.json"
    ok(run(server.url, "export", str(study.id), "--format", "json", "--output", str(exported)))
    copy = int(ok(run(server.url, "import", str(exported))).stderr.split("study ")[1].split()[0])
    info = client.study_info(copy)
    assert (info.directions, info.objective_names) == (["maximize", "minimize"], ["score", "mass"])
    assert [str(c) for c in info.constraints] == ["cost <= 5"]
    assert {tuple(t.values or []) for t in client.pareto(copy)} == front
    table = tmp_path / "two.csv"
    ok(run(server.url, "export", str(study.id), "--output", str(table)))
    header = next(csv.reader(table.read_text().splitlines()))
    assert {"values_0", "values_1", "feasible"} <= set(header)
    target = client.create_study(
        name="two-csv",
        space=SPACE,
        directions=["maximize", "minimize"],
        constraints=[{"metric": "cost", "op": "<=", "bound": 5.0}],
    ).id
    ok(run(server.url, "import", str(table), "--study", str(target)))
    assert {tuple(t.values or []) for t in client.pareto(target)} == front
    shown = ok(run(server.url, "pareto", str(target))).stdout
    assert f"{len(front)} trials on the Pareto front" in shown


def test_enqueue_from_the_command_line_and_the_sdk(server: ServerProcess, client: Client) -> None:
    study = client.create_study(name="queue", space=SPACE)
    shown = ok(run(server.url, "enqueue", str(study.id), "--params", '{"x": 2, "n": 3, "c": "z"}'))
    assert f"study {study.id}, #0) queued" in shown.stdout
    same = ok(
        run(
            server.url,
            "enqueue",
            str(study.id),
            "--params",
            '{"x": 2, "n": 3, "c": "z"}',
            "--skip-if-exists",
            "--json",
        )
    )
    assert json.loads(same.stdout)["number"] == 0
    failed_with(run(server.url, "enqueue", str(study.id), "--params", "[1]"), "JSON object", 2)
    failed_with(
        run(server.url, "enqueue", str(study.id), "--params", '{"x": 2, "n": 3, "c": 9}'),
        "'c': 9 is not one of its choices",
    )
    queued = study.enqueue_trial({"x": 0.5, "n": 2, "c": "b"})
    added = study.add_trial({"x": 1.0, "n": 1, "c": "a"}, 7.5)
    assert queued.state == "queued" and added.state == "complete"
    assert study.best_value == 7.5
    listed = ok(run(server.url, "trials", str(study.id))).stdout
    assert "queued (enqueued)" in listed and "complete (added)" in listed
    with pytest.raises(Invalid, match="value is required"):
        study.add_trial({"x": 1.0, "n": 1, "c": "a"})
    asked = study.ask(count=3)
    assert [t.number for t in asked] == [0, 1, 3] and asked[2].info["proposer"] == "qei"


def test_read_import_names_what_is_wrong() -> None:
    with pytest.raises(ImportFileError, match="not JSON"):
        read_import("{", format="json")
    with pytest.raises(ImportFileError, match="'study' and 'trials'"):
        read_import("[]", format="json")
    with pytest.raises(ImportFileError, match="a 'value' column"):
        read_import("x,n\n1,2\n", format="csv")
    with pytest.raises(ImportFileError, match="line 2, value: 'high' is not a number"):
        read_import("x,value\n1,high\n", format="csv")
    plan = read_import("x,state\n1,failed\n2,running\n", format="csv", queue_unfinished=False)
    assert [t.state for t in plan.trials] == ["failed"] and plan.left_out == 1
