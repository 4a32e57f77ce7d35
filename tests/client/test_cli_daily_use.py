"""Issue 62, the CLI's part: ``stop``, ``status --wait``, ``files`` and ``best --save``, and
errors that point at the mistake, against a real ``adserver`` (the CLI through typer's
runner, or as a real process where a signal is sent)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import threading
from pathlib import Path

import pytest
import yaml
from typer.testing import Result

from adclient import Client, Conflict
from adclient.testing.servers import ServerProcess, make_token
from adclient.testing.workers import ADCLIENT, PATIENCE, wait_for
from tests.client.cli_harness import failed_with, ok, run, write_study
from tests.client.scripted_server import Reply, ScriptedServer

BOX = {"type": "box", "params": [{"name": "x", "low": -2.0, "high": 2.0}]}
EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def box_study(client: Client, name: str, **fields: object) -> int:
    return client.create_study(name=name, space=BOX, proposer={"name": "random"}, **fields).id


def plain(server_url: str, *args: str) -> Result:
    """The CLI as a pipe or a file sees it: no ``COLUMNS``, not a terminal."""
    return run(server_url, *args, env={"COLUMNS": None})  # type: ignore[dict-item]


# -- stop ------------------------------------------------------------------------------


def test_stop_stops_a_running_study_and_says_what_became_of_its_trials(
    server: ServerProcess, client: Client
) -> None:
    study_id = box_study(client, "stop-me")
    study = client.get_study(study_id)
    running = study.ask(count=2)
    study.tell(running[0], 0.5)
    queued = client.add_trials(study_id, [{"params": {"x": 0.25}}])[0]
    assert queued.state == "queued"

    stopped = ok(run(server.url, "stop", str(study_id))).stdout
    assert f"study {study_id} stopped: no new trials are proposed or leased" in stopped
    assert "1 complete, 1 failed, 0 pruned" in stopped  # the queued one ended as failed
    assert "1 queued trials ended as failed" in stopped
    assert "1 running trials may still be told" in stopped
    assert client.study_info(study_id).state == "stopped"
    assert client.get_trial(queued.id).message == "study stopped"
    with pytest.raises(Conflict):
        study.ask()
    study.tell(running[1], 1.5)  # as the message says

    again = ok(run(server.url, "stop", str(study_id))).stdout
    assert f"study {study_id} is already stopped: nothing to stop" in again
    as_json = json.loads(ok(run(server.url, "stop", str(study_id), "--json")).stdout)
    assert as_json["state"] == "stopped" and as_json["n_complete"] == 2
    failed_with(run(server.url, "stop", "987654"), "study 987654 not found", code=1)


def test_stop_by_another_user_or_without_a_token_is_refused_with_exit_4(tmp_path: Path) -> None:
    """Exit statuses as the README's table has them: only the study's owner (or an admin)
    stops it."""
    server = ServerProcess(
        database_url=f"sqlite:///{tmp_path / 'auth.db'}", workdir=tmp_path, env={"AD_AUTH": "true"}
    ).start()
    try:
        alice, bob = make_token(server, "user", "alice"), make_token(server, "user", "bob")
        with Client(server.url, alice) as api:
            study_id = box_study(api, "alice-only")
        failed_with(run(server.url, "--token", bob, "stop", str(study_id)), "forbidden:", code=4)
        failed_with(run(server.url, "stop", str(study_id)), "unauthorized:", code=4)
        with Client(server.url, alice) as api:
            assert api.study_info(study_id).state == "running"
        stopped = ok(run(server.url, "--token", alice, "stop", str(study_id))).stdout
        assert f"study {study_id} stopped" in stopped
    finally:
        server.stop()


# -- status --wait ---------------------------------------------------------------------


def _drive_when_polled(url: str, study_id: int, count: int, stop: threading.Event) -> None:
    """Ask and tell ``count`` trials, a little apart, while the CLI follows the study."""
    with Client(url) as api:
        study = api.get_study(study_id)
        for index in range(count):
            if stop.wait(0.05):
                return
            study.tell(study.ask(), float(index))


def test_status_wait_follows_the_study_until_it_ends(server: ServerProcess, client: Client) -> None:
    study_id = box_study(client, "follow-me", direction="minimize", max_trials=4)
    stop = threading.Event()
    driver = threading.Thread(target=_drive_when_polled, args=(server.url, study_id, 4, stop))
    driver.start()
    try:
        result = ok(run(server.url, "status", str(study_id), "--wait", "--poll", "0.05"))
    finally:
        stop.set()
        driver.join()
    # The display of submit --wait: the bar on stderr, then how the study ended.
    assert f"following study {study_id} until it ends" in result.stderr
    assert "4/4" in result.stderr
    assert f"study {study_id} complete: 4 complete, 0 failed, 0 pruned" in result.stdout
    assert "best trial #0" in result.stdout and "value 0" in result.stdout

    # A study that has ended: at once, the same end; with --json, the study's record.
    again = ok(run(server.url, "status", str(study_id), "--wait"))
    assert f"study {study_id} complete: 4 complete" in again.stdout
    as_json = json.loads(ok(run(server.url, "status", str(study_id), "-w", "--json")).stdout)
    assert as_json["state"] == "complete" and as_json["n_complete"] == 4
    failed_with(run(server.url, "status", "987654", "--wait"), "study 987654 not found")


def test_ctrl_c_on_status_wait_stops_following_and_leaves_the_study_running(
    server: ServerProcess, client: Client, tmp_path: Path
) -> None:
    study_id = box_study(client, "ctrl-c", max_trials=3)
    out, err = tmp_path / "stdout", tmp_path / "stderr"
    env = {**os.environ, "AD_SERVER_URL": server.url, "NO_COLOR": "1"}
    env.pop("AD_TOKEN", None)
    with out.open("w") as stdout, err.open("w") as stderr:
        process = subprocess.Popen(
            [str(ADCLIENT), "status", str(study_id), "--wait", "--poll", "0.05"],
            stdout=stdout,
            stderr=stderr,
            env=env,
        )

    def following() -> bool:
        return "following study" in err.read_text() or process.poll() is not None

    try:
        wait_for(following, "adclient to follow the study (or end)")
        process.send_signal(signal.SIGINT)
        code = process.wait(timeout=PATIENCE)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    errors = err.read_text()
    assert code == 130, errors
    assert f"stopped waiting; study {study_id} keeps running" in errors
    assert "Traceback" not in errors + out.read_text()
    assert client.study_info(study_id).state == "running"


# -- files and best --save -------------------------------------------------------------

PNG = b"\x89PNG\r\n\x1a\n" + bytes(range(256))
CURVE = json.dumps({"steps": [0, 100], "reward": [0.0, 1.5]}).encode()
CHECKPOINT = b"PK\x03\x04" + b"\x00" * 64


def _design_trial(client: Client, name: str) -> tuple[int, int]:
    """A stand-up design study (no workers) with one complete trial that has the files a
    worker uploads (its URDF left to the server's route)."""
    space = yaml.safe_load((EXAMPLES / "stand-up.yaml").read_text())["space"]
    study = client.create_study(name=name, space=space, proposer={"name": "random"})
    trial = study.ask()
    for artifact, data, kind in (
        ("robot.png", PNG, "image/png"),
        ("curve.json", CURVE, "application/json"),
        ("checkpoint.zip", CHECKPOINT, "application/zip"),
    ):
        client.put_artifact(trial, artifact, data, kind)
    study.tell(trial, 0.75)
    return study.id, trial.id


def test_files_writes_a_trials_urdf_and_artifacts_and_never_overwrites_unasked(
    server: ServerProcess, client: Client, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    _, trial_id = _design_trial(client, "files-me")
    folder = tmp_path / "robot"
    result = ok(run(server.url, "files", str(trial_id), "--out", str(folder)))
    expected = {
        "robot.png": PNG,
        "curve.json": CURVE,
        "checkpoint.zip": CHECKPOINT,
        "robot.urdf": client.trial_urdf(trial_id).encode(),
    }
    assert {path.name: path.read_bytes() for path in folder.iterdir()} == expected
    for name in expected:
        assert f"wrote {folder / name} (" in result.stdout
    assert f"trial {trial_id}: 4 files in {folder}" in result.stdout
    assert "<robot" in (folder / "robot.urdf").read_text()

    (folder / "robot.png").write_bytes(b"mine")
    refused = run(server.url, "files", str(trial_id), "--out", str(folder))
    failed_with(refused, "give --force to overwrite (nothing written)")
    assert "robot.png" in refused.stderr
    assert (folder / "robot.png").read_bytes() == b"mine"
    ok(run(server.url, "files", str(trial_id), "--out", str(folder), "--force"))
    assert (folder / "robot.png").read_bytes() == PNG

    monkeypatch.chdir(tmp_path)  # no --out: a folder named after the trial, here
    ok(run(server.url, "files", str(trial_id)))
    assert sorted(path.name for path in (tmp_path / f"trial-{trial_id}").iterdir()) == sorted(
        expected
    )
    failed_with(run(server.url, "files", "987654"), "trial 987654 not found")
    bare = client.get_study(box_study(client, "no-files")).ask()
    failed_with(run(server.url, "files", str(bare.id), "-o", str(tmp_path / "x")), "no files")
    assert not (tmp_path / "x").exists()


def test_best_save_writes_the_best_designs_files(
    server: ServerProcess, client: Client, tmp_path: Path
) -> None:
    study_id, trial_id = _design_trial(client, "best-files")
    folder = tmp_path / "best"
    result = ok(run(server.url, "best", str(study_id), "--save", str(folder)))
    assert f"best trial #0 (id {trial_id}): value 0.75" in result.stdout
    assert f"trial {trial_id}: 4 files in {folder}" in result.stdout
    assert (folder / "robot.png").read_bytes() == PNG
    assert (folder / "robot.urdf").read_text() == client.trial_urdf(trial_id)

    # JSON stays alone on stdout; what was written goes to stderr.
    again = ok(run(server.url, "best", str(study_id), "--json", "--save", str(folder), "--force"))
    assert json.loads(again.stdout)["id"] == trial_id
    assert f"trial {trial_id}: 4 files in {folder}" in again.stderr
    failed_with(run(server.url, "best", str(study_id), "--save", str(folder)), "--force")


def test_files_never_follow_a_link_out_of_the_folder(
    server: ServerProcess, client: Client, tmp_path: Path
) -> None:
    _, trial_id = _design_trial(client, "links")
    folder, outside = tmp_path / "robot", tmp_path / "precious.png"
    folder.mkdir()
    outside.write_bytes(b"precious")
    (folder / "robot.png").symlink_to(outside)
    failed_with(run(server.url, "files", str(trial_id), "-o", str(folder)), "--force")
    ok(run(server.url, "files", str(trial_id), "-o", str(folder), "--force"))
    assert outside.read_bytes() == b"precious"  # the link was replaced, not written through
    assert not (folder / "robot.png").is_symlink()
    assert (folder / "robot.png").read_bytes() == PNG


def test_files_write_no_name_a_hostile_server_sends_outside_the_folder(
    client: Client, tmp_path: Path
) -> None:
    """A server (or whoever uploaded) may name an artifact anything: only plain file names
    are written, inside the folder; the others are named in the error."""
    study_id = box_study(client, "hostile")
    trial = client.get_study(study_id).ask()
    hostile = [
        "../escaped.txt",
        "/tmp/absolute.txt",
        "sub/dir.txt",
        ".hidden",
        "..",
        "robot.png\n",
        "ROBOT.PNG",  # the same file as robot.png on a case-blind disk
    ]
    listing = [
        {"name": name, "size": 3, "content_type": "text/plain", "created_at": "2026-01-01T00:00:00"}
        for name in ["robot.png", *hostile]
    ]
    scripted = ScriptedServer().start()
    try:
        scripted.play(
            Reply(200, trial.model_dump(mode="json")),
            Reply(200, listing),
            Reply(200, raw=b"png", headers={"Content-Type": "image/png"}),
            Reply(200, client.study_info(study_id).model_dump(mode="json")),
        )
        folder = tmp_path / "deep" / "folder"
        result = run(scripted.url, "files", str(trial.id), "-o", str(folder))
    finally:
        scripted.stop()
    failed_with(result, "not written: '../escaped.txt', '/tmp/absolute.txt'")
    assert "'ROBOT.PNG'" in result.stderr and "'robot.png\\n'" in result.stderr
    assert [path.name for path in folder.iterdir()] == ["robot.png"]
    assert sorted(path.name for path in tmp_path.rglob("*") if path.is_file()) == ["robot.png"]
    assert not Path("/tmp/absolute.txt").exists()


# -- errors that point at the mistake --------------------------------------------------


def test_a_server_url_without_a_scheme_is_a_usage_error_naming_it(server: ServerProcess) -> None:
    bare = server.url.removeprefix("http://")
    result = run(bare, "studies")
    failed_with(result, f"'{bare}' has no scheme: give {server.url} (or https://)", code=2)
    failed_with(run("", "studies", env={"AD_SERVER_URL": f"ftp://{bare}"}), "ftp://", code=2)
    ok(run(server.url, "studies"))  # the server was there all along


def test_study_file_errors_give_the_line_and_column(server: ServerProcess, tmp_path: Path) -> None:
    flow = tmp_path / "flow.yaml"
    flow.write_text("name: broken\nspace: {type: box,\n  params: [}\n")
    failed_with(
        run(server.url, "submit", str(flow)),
        f"cannot parse {flow} at line 3, column 12: expected the node content, but found '}}'",
    )
    indented = tmp_path / "indented.yaml"
    indented.write_text("name: a\n  max_trials: 3\n")
    failed_with(
        run(server.url, "submit", str(indented)),
        f"cannot parse {indented} at line 2, column 13: mapping values are not allowed here",
    )
    broken = tmp_path / "broken.json"
    broken.write_text('{\n  "name": "j",\n  "space" {}\n}\n')
    failed_with(
        run(server.url, "submit", str(broken)),
        f"cannot parse {broken} at line 3, column 11: Expecting ':' delimiter",
    )
    # A file that is not there is bad usage (2), as the README's table has it.
    failed_with(run(server.url, "submit", str(tmp_path / "missing.yaml")), "cannot read", code=2)


def test_unknown_fields_get_the_closest_valid_name(server: ServerProcess, tmp_path: Path) -> None:
    body = {
        "name": "typos",
        "max_trial": 5,
        "space": {"type": "box", "params": [{"name": "x", "low": 0.0, "hihg": 1.0}]},
        "proposer": {"name": "random", "sed": 3},
        "zzzz": 1,  # nothing close: the server's word alone
    }
    result = run(server.url, "submit", str(write_study(tmp_path, body)))
    failed_with(result, "max_trial: Extra inputs are not permitted (did you mean `max_trials`?)")
    assert "space.box.params.0.hihg: Extra inputs are not permitted (did you mean `high`?)" in (
        result.stderr
    )
    assert "proposer.sed: Extra inputs are not permitted (did you mean `seed`?)" in result.stderr
    assert result.stderr.strip().endswith("zzzz: Extra inputs are not permitted")

    design = yaml.safe_load((EXAMPLES / "stand-up.yaml").read_text())
    design["space"]["parts"]["link"]["lenght"] = 0.3
    design["task"]["trian_steps"] = 2048
    result = run(server.url, "submit", str(write_study(tmp_path, design)))
    failed_with(result, "space.design.parts.link.lenght: Extra inputs are not permitted")
    assert "(did you mean `length`?)" in result.stderr
    assert "task.trian_steps: Extra inputs are not permitted (did you mean `train_steps`?)" in (
        result.stderr
    )


def test_errors_and_tables_are_not_cut_at_80_columns_off_a_terminal(
    server: ServerProcess, client: Client, tmp_path: Path
) -> None:
    long_name = "a-study-whose-name-is-long-" * 5
    study_id = box_study(client, long_name)
    space = {
        "type": "box",
        "params": [{"name": f"parameter_with_a_long_name_{i}", "low": 0, "high": 1} for i in "ab"],
    }
    wide = client.create_study(name="wide-params", space=space, proposer={"name": "random"})
    trial = wide.ask()
    listed = ok(plain(server.url, "studies")).stdout
    rows = [[cell.strip() for cell in line.split("│")] for line in listed.splitlines()]
    assert any(str(study_id) in row and long_name in row for row in rows), listed
    params = ok(plain(server.url, "trials", str(wide.id))).stdout
    first = f"parameter_with_a_long_name_a={trial.params['parameter_with_a_long_name_a']:.6g}"
    second = "parameter_with_a_long_name_b="
    assert any(first in line and second in line for line in params.splitlines()), params

    reversed_box = {"type": "box", "params": [{"name": "x", "low": 3.0, "high": 1.0}]}
    body = {"name": "long-error", "space": reversed_box, "direction": "sideways"}
    result = plain(server.url, "submit", str(write_study(tmp_path, body)))
    failed_with(result, "invalid request: ")  # one line, however long
    assert len(result.stderr.strip()) > 100 and "direction" in result.stderr
