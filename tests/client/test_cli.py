"""The ``adclient`` CLI against a real ``adserver`` process, through typer's CliRunner."""

from __future__ import annotations

import csv
import io
import json
import threading
from collections.abc import Callable, Mapping
from pathlib import Path

import pytest
import yaml
from typer.testing import Result

from adclient import Client, Conflict
from adclient.client import StudyHandle
from adclient.testing.servers import ServerProcess
from tests.client.cli_harness import failed_with, ok, run, write_study
from tests.client.scripted_server import Reply, ScriptedServer, refused_url

BOX = {"type": "box", "params": [{"name": "x", "low": -2.0, "high": 2.0}]}


def make_study(client: Client, name: str, **fields: object) -> int:
    study = client.create_study(name=name, space=BOX, proposer={"name": "random"}, **fields)
    return study.id


def test_submit_yaml_prints_id_and_dashboard(
    server: ServerProcess, client: Client, tmp_path: Path
) -> None:
    body = {
        "name": "from-yaml",
        "direction": "minimize",
        "space": BOX,
        "proposer": {"name": "sobol"},
        "max_trials": 4,
    }
    result = ok(run(server.url, "submit", str(write_study(tmp_path, body))))
    study = next(s for s in client.studies() if s.name == "from-yaml")
    assert f"study {study.id} created: from-yaml" in result.stdout
    assert f"{server.url}/#/studies/{study.id}" in result.stdout
    assert study.direction == "minimize" and study.max_trials == 4
    assert study.proposer.name == "sobol"


def test_submit_json_quiet_prints_only_the_id(
    server: ServerProcess, client: Client, tmp_path: Path
) -> None:
    body = {"name": "from-json", "space": BOX, "proposer": {"name": "random"}}
    result = ok(run(server.url, "submit", "-q", str(write_study(tmp_path, body, ".json"))))
    study_id = int(result.stdout.strip())
    assert client.study_info(study_id).name == "from-json"


def submit_wait_driven(
    server: ServerProcess,
    tmp_path: Path,
    body: Mapping[str, object],
    drive: Callable[[StudyHandle, threading.Event], None],
) -> Result:
    """``adclient submit --wait`` of ``body`` while a thread drives the study (ask and
    tell) once it exists, until ``drive`` returns or the wait ends."""
    stop = threading.Event()

    def driver() -> None:
        with Client(server.url) as api:
            while not stop.is_set():
                study = next((s for s in api.studies() if s.name == body["name"]), None)
                if study is not None:
                    drive(api.get_study(study.id), stop)
                    return
                stop.wait(0.02)

    thread = threading.Thread(target=driver, daemon=True)
    thread.start()
    try:
        return run(
            server.url, "submit", "--wait", "--poll", "0.05", str(write_study(tmp_path, body))
        )
    finally:
        stop.set()
        thread.join()


def test_submit_wait_follows_until_the_budget_is_spent(
    server: ServerProcess, tmp_path: Path
) -> None:
    """A non-managed study finished by a background ask/tell loop while --wait polls."""
    body = {
        "name": "waited",
        "direction": "minimize",
        "space": BOX,
        "proposer": {"name": "random", "seed": 1},
        "max_trials": 6,
    }
    told: list[float] = []

    def drive(handle: StudyHandle, stop: threading.Event) -> None:
        while not stop.is_set():
            try:
                trial = handle.ask()
            except Conflict:  # budget spent: the study is complete
                return
            value = (trial.params["x"] - 0.5) ** 2
            handle.tell(trial, value)
            told.append(value)
            stop.wait(0.02)

    result = ok(submit_wait_driven(server, tmp_path, body, drive))
    assert len(told) == 6
    assert "6 complete, 0 failed" in result.stdout
    assert f"value {min(told):.6g}" in result.stdout
    assert "best trial #" in result.stdout
    assert "6/6" in result.stderr  # the progress bar, on stderr


def test_submit_wait_and_trials_say_why_trials_failed(
    server: ServerProcess, tmp_path: Path
) -> None:
    """Issue 39: the reasons, commonest first, where people look (not only in --json)."""
    body = {"name": "all-failing", "space": BOX, "proposer": {"name": "random"}, "max_trials": 4}
    messages = ["the function returned value = nan"] * 3 + ["[bold]target out of reach[/bold]"]

    def drive(handle: StudyHandle, _: threading.Event) -> None:
        for message in messages:
            handle.tell(handle.ask(), state="failed", message=message)

    result = ok(submit_wait_driven(server, tmp_path, body, drive))
    lines = [line.strip() for line in result.stdout.splitlines()]
    at = lines.index("why trials failed:")
    assert "0 complete, 4 failed" in lines[at - 1]
    assert lines[at + 1 : at + 3] == [
        "3 x the function returned value = nan",
        "1 x [bold]target out of reach[/bold]",  # a message is text, never markup
    ]
    assert "no complete trial" in lines
    study_id = lines[0].split()[1]
    listed = ok(run(server.url, "trials", study_id)).stdout
    assert "message" in listed.splitlines()[2]  # the header, after the title and a rule
    assert listed.count("the function returned value = nan") == 3
    assert "[bold]target out of reach[/bold]" in listed


def test_submit_wait_on_a_stopped_study_reports_no_complete_trial(
    server: ServerProcess, client: Client, tmp_path: Path
) -> None:
    body = {"name": "stopped-early", "space": BOX, "proposer": {"name": "random"}}
    stopper = threading.Thread(target=_stop_when_created, args=(server.url, "stopped-early"))
    stopper.start()
    result = run(server.url, "submit", "--wait", "--poll", "0.05", str(write_study(tmp_path, body)))
    stopper.join()
    ok(result)
    assert "stopped: 0 complete, 0 failed" in result.stdout
    assert "no complete trial" in result.stdout


def _stop_when_created(url: str, name: str) -> None:
    with Client(url) as api:
        while True:
            study = next((s for s in api.studies() if s.name == name), None)
            if study is not None:
                api.stop_study(study.id)
                return
            threading.Event().wait(0.02)


def test_submit_invalid_study_names_the_field(server: ServerProcess, tmp_path: Path) -> None:
    bad = {
        "name": "bad",
        "space": {"type": "box", "params": [{"name": "x", "low": 3.0, "high": 1.0}]},
    }
    failed_with(run(server.url, "submit", str(write_study(tmp_path, bad))), "invalid request:")
    result = run(server.url, "submit", str(write_study(tmp_path, bad)))
    assert "low" in result.stderr and "high" in result.stderr


def test_submit_unreadable_or_unparsable_file(server: ServerProcess, tmp_path: Path) -> None:
    failed_with(run(server.url, "submit", str(tmp_path / "missing.yaml")), "cannot read", 2)
    broken = tmp_path / "broken.yaml"
    broken.write_text("name: [unclosed\n")
    failed_with(run(server.url, "submit", str(broken)), "cannot parse")
    scalar = tmp_path / "scalar.json"
    scalar.write_text("42")
    failed_with(run(server.url, "submit", str(scalar)), "must hold a mapping")


def test_studies_lists_every_study(server: ServerProcess, client: Client) -> None:
    first = make_study(client, "listed-one")
    second = make_study(client, "listed-two", max_trials=9)
    result = ok(run(server.url, "studies"))
    assert "listed-one" in result.stdout and "listed-two" in result.stdout
    assert "0/9" in result.stdout
    as_json = json.loads(ok(run(server.url, "studies", "--json")).stdout)
    assert {first, second} <= {item["id"] for item in as_json}


def test_status_shows_counts_and_best(server: ServerProcess, client: Client) -> None:
    study_id = make_study(client, "status-me", direction="minimize", max_trials=5)
    study = client.get_study(study_id)
    trials = study.ask(count=3)
    study.tell(trials[0], 0.125)
    study.tell(trials[1], state="failed", message="crashed")
    result = ok(run(server.url, "status", str(study_id)))
    text = result.stdout
    assert f"study {study_id}: status-me" in text
    for field, value in [
        ("trials", "3/5"),
        ("running", "1"),
        ("complete", "1"),
        ("failed", "1"),
        ("best value", "0.125"),
    ]:
        assert any(field in line and value in line for line in text.splitlines()), field
    assert f"/#/studies/{study_id}" in text
    as_json = json.loads(ok(run(server.url, "status", str(study_id), "--json")).stdout)
    assert as_json["n_complete"] == 1 and as_json["best_value"] == 0.125


def test_trials_lists_and_filters_by_state(server: ServerProcess, client: Client) -> None:
    study_id = make_study(client, "trials-me")
    study = client.get_study(study_id)
    trials = study.ask(count=3)
    study.tell(trials[0], 1.5)
    study.tell(trials[2], 2.5)
    result = ok(run(server.url, "trials", str(study_id)))
    assert "3 trials" in result.stdout
    assert result.stdout.count("complete") == 2 and "running" in result.stdout
    complete = json.loads(
        ok(run(server.url, "trials", str(study_id), "--state", "complete", "--json")).stdout
    )
    assert [item["id"] for item in complete] == [trials[0].id, trials[2].id]
    running = ok(run(server.url, "trials", str(study_id), "--state", "running"))
    assert "1 trials" in running.stdout
    bad_state = run(server.url, "trials", str(study_id), "--state", "sleeping")
    assert bad_state.exit_code == 2


def test_best_shows_the_best_trial_or_says_there_is_none(
    server: ServerProcess, client: Client
) -> None:
    study_id = make_study(client, "best-me", direction="maximize")
    failed_with(run(server.url, "best", str(study_id)), f"study {study_id} has no complete trial")
    study = client.get_study(study_id)
    low, high = study.ask(count=2)
    study.tell(low, 1.0)
    study.tell(high, 7.0, metrics={"reward_std": 0.5})
    result = ok(run(server.url, "best", str(study_id)))
    assert f"best trial #{high.number} (id {high.id}): value 7" in result.stdout
    assert "metric reward_std" in result.stdout
    assert json.loads(ok(run(server.url, "best", str(study_id), "--json")).stdout)["id"] == high.id


def test_ask_then_tell_by_hand(server: ServerProcess, client: Client) -> None:
    study_id = make_study(client, "by-hand", direction="minimize")
    asked = json.loads(ok(run(server.url, "ask", str(study_id), "--count", "3", "--json")).stdout)
    assert [item["state"] for item in asked] == ["running"] * 3
    table = ok(run(server.url, "ask", str(study_id)))
    assert "1 new trials" in table.stdout and "x=" in table.stdout

    first, second, third = (item["id"] for item in asked)
    told = ok(run(server.url, "tell", str(first), "0.75", "--metric", "steps=100"))
    assert f"trial {first}" in told.stdout and "complete: value 0.75" in told.stdout
    ok(run(server.url, "tell", str(first), "0.75"))  # repeating is harmless
    failed = ok(run(server.url, "tell", str(second), "--failed", "--message", "fell over"))
    assert "failed" in failed.stdout
    trials = {trial.id: trial for trial in client.trials(study_id)}
    assert trials[first].value == 0.75 and trials[first].metrics == {"steps": 100.0}
    assert trials[second].state == "failed" and trials[second].message == "fell over"

    failed_with(run(server.url, "tell", str(first), "0.5"), "conflict:")
    failed_with(run(server.url, "tell", str(third), "nan"), "invalid request:")
    failed_with(run(server.url, "tell", str(third)), "missing VALUE", code=2)
    failed_with(run(server.url, "tell", str(third), "1", "--failed"), "not both", code=2)
    failed_with(run(server.url, "tell", str(third), "1", "--metric", "oops"), "NAME=NUMBER", 2)
    failed_with(run(server.url, "ask", str(study_id), "--count", "65"), "invalid request:")
    assert client.get_trial(third).state == "running", "no bad tell stored anything"


def test_export_csv_and_json(server: ServerProcess, client: Client, tmp_path: Path) -> None:
    study_id = make_study(client, "export-me", direction="minimize")
    study = client.get_study(study_id)
    study.optimize(lambda trial: trial.params["x"] ** 2, 3)

    rows = list(csv.DictReader(io.StringIO(ok(run(server.url, "export", str(study_id))).stdout)))
    assert [row["number"] for row in rows] == ["0", "1", "2"]
    values = {trial.number: trial.value for trial in study.trials}
    assert {int(row["number"]): float(row["value"]) for row in rows} == values
    assert all(row["params_x"] for row in rows)

    target = tmp_path / "out.json"
    result = ok(run(server.url, "export", str(study_id), "--format", "json", "-o", str(target)))
    assert result.stdout == ""
    assert str(target) in result.stderr
    exported = json.loads(target.read_text())
    assert exported["study"]["name"] == "export-me"
    assert len(exported["trials"]) == 3
    failed_with(run(server.url, "export", str(study_id), "--format", "xml"), "csv or json", 2)


@pytest.mark.parametrize(
    "args",
    [
        ["status", "987654"],
        ["trials", "987654"],
        ["best", "987654"],
        ["ask", "987654"],
        ["export", "987654"],
    ],
)
def test_unknown_study_is_named(server: ServerProcess, args: list[str]) -> None:
    failed_with(run(server.url, *args), "study 987654 not found")


def test_unknown_trial_is_named(server: ServerProcess) -> None:
    failed_with(run(server.url, "tell", "987654", "1.0"), "trial 987654 not found")


def test_unreachable_server(tmp_path: Path) -> None:
    """Exit status 3: no server to talk to (a script may retry later)."""
    url = refused_url()
    failed_with(run(url, "studies"), f"cannot reach server at {url}", code=3)
    study = write_study(tmp_path, {"name": "nowhere", "space": BOX})
    failed_with(run(url, "submit", str(study)), f"cannot reach server at {url}", code=3)


def test_server_and_token_come_from_the_environment() -> None:
    scripted = ScriptedServer().start()
    try:
        scripted.play(Reply(401, {"error": "unauthorized", "detail": "missing bearer token"}))
        result = run("", "studies", env={"AD_SERVER_URL": scripted.url, "AD_TOKEN": "t0k"})
        failed_with(result, "unauthorized: missing bearer token", code=4)
        assert scripted.seen[0].headers["Authorization"] == "Bearer t0k"
        scripted.play(Reply(403, {"error": "forbidden", "detail": "reader may not ask"}))
        failed_with(
            run(scripted.url, "--token", "r", "ask", "1"), "forbidden: reader may not ask", code=4
        )
        scripted.play(Reply(503, {"error": "unavailable", "detail": "draining"}))
        failed_with(run(scripted.url, "studies"), "unavailable: draining (HTTP 503)", code=3)
        scripted.play(Reply(422, {"error": "invalid", "detail": "count: too many"}))
        failed_with(run(scripted.url, "ask", "1"), "invalid request: count: too many", code=1)
    finally:
        scripted.stop()


def test_version_and_help() -> None:
    assert "adclient 0.1.0" in ok(run("", "--version")).stdout
    assert "submit" in ok(run("", "--help")).stdout


def test_typed_params_in_status_trials_best_and_export(
    server: ServerProcess, client: Client
) -> None:
    """Ints, log floats and choices as the SDK gets them (ints as int, a choice as given),
    in the CLI's tables and in both exports."""
    space = {
        "type": "box",
        "params": [
            {"name": "lr", "low": 1e-4, "high": 1.0, "log": True},
            {"name": "width", "type": "int", "low": 8, "high": 512, "log": True},
            {"name": "act", "type": "categorical", "choices": ["relu", "tanh"]},
        ],
    }
    study = client.create_study(name="typed-cli", space=space, proposer={"name": "tpe"})
    study.optimize(lambda t: t.params["width"] * (2 if t.params["act"] == "tanh" else 1), 4)
    trials = study.trials
    assert all(
        type(t.params["width"]) is int and t.params["act"] in ("relu", "tanh") for t in trials
    )
    assert all(type(t.params["lr"]) is float for t in trials)

    status = ok(run(server.url, "status", str(study.id))).stdout
    assert "width int [8, 512] log" in status and "lr float [0.0001, 1] log" in status
    assert "act in {relu, tanh}" in status
    listed = ok(run(server.url, "trials", str(study.id))).stdout
    for trial in trials:
        assert f"width={trial.params['width']}, act={trial.params['act']}" in listed
    rows = list(csv.DictReader(io.StringIO(ok(run(server.url, "export", str(study.id))).stdout)))
    by_number = {int(row["number"]): row for row in rows}
    for trial in trials:
        row = by_number[trial.number]
        assert row["params_width"] == str(trial.params["width"])  # no ".0"
        assert row["params_act"] == trial.params["act"]
        assert float(row["params_lr"]) == trial.params["lr"]
    exported = json.loads(ok(run(server.url, "export", str(study.id), "--format", "json")).stdout)
    assert [t["params"] for t in exported["trials"]] == [t.params for t in trials]
    assert exported["study"]["space"]["params"][2]["choices"] == ["relu", "tanh"]


def test_best_and_trials_show_what_a_design_study_searched(server: ServerProcess) -> None:
    """Issue 40: the best design by its searched params, the whole one a flag away."""
    example = yaml.safe_load(
        (Path(__file__).resolve().parents[2] / "examples" / "stand-up.yaml").read_text()
    )
    body = {"name": "searched", "space": example["space"], "proposer": {"name": "random"}}
    with Client(server.url) as api:
        study = api.create_study(body)
        trial = study.ask()
        study.tell(trial, 0.5)
    searched = {"a.length", "b.length", "c.length", "b.joint.axis", "c.joint.axis"}
    fixed = sorted(set(trial.params) - searched)
    assert "a.radius" in fixed and "b.joint.effort" in fixed

    best = ok(run(server.url, "best", str(study.id))).stdout
    rows = {line.split("│")[1].strip() for line in best.splitlines() if line.count("│") >= 3}
    assert rows - {"param"} == searched
    assert f"{len(fixed)} more are fixed by the study file" in " ".join(best.split())
    whole = ok(run(server.url, "best", str(study.id), "--all")).stdout
    rows = {line.split("│")[1].strip() for line in whole.splitlines() if line.count("│") >= 3}
    assert rows - {"param"} == set(trial.params)
    assert "more are fixed" not in whole

    listed = ok(run(server.url, "trials", str(study.id))).stdout
    assert "b.length" in listed and "a.radius" not in listed
    assert "a.radius" in ok(run(server.url, "trials", str(study.id), "--all")).stdout
