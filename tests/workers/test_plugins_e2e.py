"""A third-party plugin package, really pip-installed, runs a managed study end to end:
a real adserver checks the study with the plugin's declarations, a real adworker runs
its task with its learner, and a worker without the plugin leaves its trials alone.

The package (tests/workers/plugin_fixture) is installed into a folder of its own that
only the spawned server and worker processes see (PYTHONPATH: conftest's
``plugin_site``), so the venv, and every other test, stays as it was."""

from __future__ import annotations

import csv
import io
import json
import math
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
import yaml
from PIL import Image

from adclient import Client
from adclient.plugins import catalogue
from adclient.testing.servers import ServerProcess
from adclient.testing.workers import PATIENCE, WorkerProcess, completed_trials, plugin_path
from tests.service.chromium import Chromium
from tests.service.dashboard_pages import STUDY_PAGE_READY

pytestmark = pytest.mark.e2e

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


@pytest.fixture
def server(plugin_server: ServerProcess) -> ServerProcess:
    """Every server here has the plugin."""
    return plugin_server


@pytest.fixture(scope="module")
def checking_server(
    plugin_site: Path, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[ServerProcess]:
    """One server that has the plugin, for the tests that only read its catalogue or are
    refused a study (they run on one xdist process, group ``plugin-checks``)."""
    work = tmp_path_factory.mktemp("plugin-checks")
    server = ServerProcess(
        database_url=f"sqlite:///{work / 'studies.db'}", workdir=work, env=plugin_path(plugin_site)
    ).start()
    try:
        yield server
    finally:
        server.stop()


def reach_up_study(**task: Any) -> dict[str, Any]:
    """diagonal-gesture's arm with searched link lengths, scored by the plugin's task."""
    body = yaml.safe_load((EXAMPLES / "diagonal-gesture.yaml").read_text())
    body["name"] = "reach"
    body["space"]["parts"]["link"]["length"] = {"low": 0.2, "high": 0.6}
    body["proposer"] = {"name": "random", "seed": 1}
    body["task"] = {"name": "reach-up", "learner": "hold", "eval_episodes": 1, **task}
    body["max_trials"] = 3
    return body


@pytest.mark.xdist_group("plugin-checks")
def test_the_catalogue_lists_the_plugin_with_its_option_schemas(
    checking_server: ServerProcess,
) -> None:
    with Client(checking_server.url) as client:
        tasks = {task.name: task for task in client.tasks()}
        learners = {learner.name: learner for learner in client.learners()}
    assert sorted(tasks) == sorted(
        [*catalogue().tasks, "reach-up", "reach-point", "arm-length", "reach-elsewhere"]
    )
    reach = tasks["reach-up"]
    assert "fixed base" in reach.description
    assert reach.simulators == ["pybullet"]  # its TaskSpec names no other engine
    tip = reach.options_schema["properties"]["tip_link"]
    assert (tip["default"], tip["minLength"]) == ("c", 1)
    assert reach.options_schema["properties"]["frame_skip"]["default"] == 12
    assert tasks["stand-up"].options_schema["properties"]["feet_links"]["default"] == ["a", "c"]
    assert learners["hold"].options_schema is not None
    assert learners["hold"].options_schema["properties"]["pose"]["maximum"] == 1.0
    assert learners["fast"].options_schema is None
    assert learners["ppo"].options_schema is not None


@pytest.mark.xdist_group("plugin-checks")
@pytest.mark.parametrize(
    ("task", "named"),
    [
        (
            {"name": "reach-down"},
            ["task.name", "unknown task 'reach-down'", "reach-up, reach-workspace, stand-up"],
        ),
        (
            {"learner": "grasp"},
            ["task.learner", "unknown learner 'grasp'", "fast, hold, mpc, ppo, ppo-batch"],
        ),
        ({"options": {"tip_link": ""}}, ["task.options: tip_link:", "at least 1 character"]),
        ({"options": {"reach": 2}}, ["unknown option of task 'reach-up'", "tip_link"]),
        ({"options": {"learner_kwargs": {"pose": 2}}}, ["learner_kwargs.pose:", "1"]),
        ({"options": {"tip_link": "hand"}}, ["looks up link 'hand' (task.options.tip_link)"]),
        ({"simulator": "mujoco"}, ["task 'reach-up' does not run on 'mujoco'", "pybullet)"]),
    ],
)
def test_a_study_of_the_plugin_is_checked_with_its_declarations(
    checking_server: ServerProcess, task: dict[str, Any], named: list[str]
) -> None:
    url = f"{checking_server.url}/api/v1/studies"
    answer = httpx.post(url, json=reach_up_study(**task), timeout=60)
    assert answer.status_code == 422, answer.text
    detail = answer.json()["detail"]
    for text in named:
        assert text in detail, (text, detail)
    assert httpx.get(url, timeout=60).json() == [], "a refused study was stored"


def test_the_command_lines_list_the_plugin_and_what_does_not_load_here(plugin_site: Path) -> None:
    env = {**os.environ, **plugin_path(plugin_site)}
    bin_dir = Path(sys.executable).parent
    listed = {}
    for command in ("adserver", "adworker"):
        done = subprocess.run(
            [str(bin_dir / command), "tasks"], env=env, capture_output=True, text=True, check=True
        )
        listed[command] = {line.split()[0]: line for line in done.stdout.splitlines()}
    assert "does not load" not in "".join(listed["adserver"].values()), "the server imports none"
    worker = listed["adworker"]
    assert "fixed base" in worker["reach-up"] and "does not load" not in worker["reach-up"]
    assert "hold" in worker and "does not load" not in worker["hold"]
    elsewhere = worker["reach-elsewhere"]
    assert "does not load: ModuleNotFoundError" in elsewhere
    assert "simulator_that_is_not_installed" in elsewhere


def test_a_plugin_task_runs_end_to_end_and_only_workers_with_it_lease_it(
    server: ServerProcess, plugin_site: Path, tmp_path: Path
) -> None:
    started: list[WorkerProcess] = []
    try:
        with Client(server.url) as client:
            study = client.create_study(reach_up_study(options={"learner_kwargs": {"pose": 0}}))
            elsewhere = client.create_study(reach_up_study(name="reach-elsewhere"))
            without = WorkerProcess(server, tmp_path, "without", "--idle-exit", "3")
            started.append(without)
            assert without.wait() == 0, without.log()
            assert "reach-up" not in without.log().split("tasks", 1)[1].splitlines()[0]
            assert client.study_info(study.id).n_trials == 0, "leased by a worker without it"

            env = plugin_path(plugin_site)
            with_it = WorkerProcess(server, tmp_path, "with", "--max-jobs", "3", env=env)
            started.append(with_it)
            assert with_it.wait() == 0, with_it.log()
            leased = with_it.log().split("tasks", 1)[1].splitlines()[0]
            assert "'reach-up'" in leased and "reach-elsewhere" not in leased
            assert "task reach-elsewhere: its environment does not load" in with_it.log()
            # hold is written against the learner interface before issue 38: it trains
            assert "learner Hold: train(env, *, steps, seed, check) configured" in with_it.log()
            assert client.study_info(elsewhere.id).n_trials == 0
            # Each named the learners that load on it: the plugin's only where it is.
            learners = {worker.worker_id: worker.learners for worker in client.workers()}
            assert learners["with"] is not None and "hold" in learners["with"]
            assert learners["without"] is not None and "hold" not in learners["without"]
            assert "fast" in learners["without"]
            final = study.wait(poll=1.0, timeout=PATIENCE)
            assert final.n_complete == 3, [trial.message for trial in study.trials]
            for trial in study.trials:
                assert trial.worker_id == "with"
                assert trial.metrics["train_steps"] == 0  # the hold learner's
                # Held straight up on its fixed base: the tip's top is the arm's length.
                length = sum(trial.params[f"{link}.length"] for link in "abc")
                assert trial.value == pytest.approx(length, abs=0.01), trial.params
                names = {artifact.name for artifact in client.artifacts(trial)}
                assert names == {"robot.urdf", "robot.png", "curve.json", "replay.json"}
    finally:
        for worker in started:
            worker.stop()


REACH_TARGET = (0.4, 0.3, 0.5)


@pytest.fixture(scope="module")
def reach_point_run(
    plugin_site: Path, tmp_path_factory: pytest.TempPathFactory
) -> Iterator[tuple[ServerProcess, int, list[Any]]]:
    """A real server and worker that have the plugin ran a study of reach-point that
    minimises, and constrains, the task's own task.tip_distance: (server, study id, its
    two complete trials)."""
    work = tmp_path_factory.mktemp("reach-point")
    server = ServerProcess(
        database_url=f"sqlite:///{work / 'studies.db'}", workdir=work, env=plugin_path(plugin_site)
    ).start()
    body = reach_up_study(name="reach-point", options={"target": list(REACH_TARGET)})
    del body["direction"]
    body["objectives"] = [{"metric": "task.tip_distance", "direction": "minimize"}]
    body["constraints"] = [{"metric": "task.tip_distance", "op": "<=", "bound": 1.0}]
    body["max_trials"] = 2
    worker = WorkerProcess(server, work, "with", "--max-jobs", "2", env=plugin_path(plugin_site))
    try:
        with Client(server.url) as client:
            study = client.create_study(body)
            assert worker.wait() == 0, worker.log()
            trials = completed_trials(study, 2)
        yield server, study.id, trials
    finally:
        worker.stop()
        server.stop()


@pytest.mark.xdist_group("browser")  # with the dashboard's test: they share reach_point_run
def test_a_plugin_tasks_own_metric_and_markers_reach_the_trial_and_its_exports(
    reach_point_run: tuple[ServerProcess, int, list[Any]],
) -> None:
    """reach-point reports its final tip distance and marks its target and tip (issue
    39): the worker reports it as task.tip_distance, the study minimises and constrains
    on it, the exports have it, and robot.png has the markers' colours."""
    server, study_id, trials = reach_point_run
    with Client(server.url) as client:
        for trial in trials:
            # Held straight up on its fixed base: the tip is at the arm's length.
            length = sum(trial.params[f"{link}.length"] for link in "abc")
            distance = math.dist((0.0, 0.0, length), REACH_TARGET)
            assert trial.metrics["task.tip_distance"] == pytest.approx(distance, abs=0.01)
            assert trial.value == trial.metrics["task.tip_distance"]  # the objective
            assert trial.feasible is (trial.value <= 1.0)
            png = client.get_artifact(trial, "robot.png")
            colours = {
                tuple(pixel)
                for pixel in np.asarray(Image.open(io.BytesIO(png)))[..., :3]
                .reshape(-1, 3)
                .tolist()
            }
            assert {(0, 204, 0), (0, 0, 255)} <= colours  # target and tip
        exported = json.loads(client.export(study_id, "json"))
        rows = list(csv.DictReader(io.StringIO(client.export(study_id, "csv"))))
    by_id = {trial.id: trial.metrics["task.tip_distance"] for trial in trials}
    assert {t["id"]: t["metrics"]["task.tip_distance"] for t in exported["trials"]} == by_id
    assert {int(row["id"]): float(row["metrics_task.tip_distance"]) for row in rows} == by_id


@pytest.mark.browser
@pytest.mark.xdist_group("browser")
def test_the_dashboards_trial_view_shows_a_plugin_tasks_own_metric(
    reach_point_run: tuple[ServerProcess, int, list[Any]], browser: Chromium
) -> None:
    server, study_id, trials = reach_point_run
    first = trials[0]
    row = f"document.querySelector('tr[data-trial-id=\"{first.id}\"]')"
    browser.navigate(f"{server.url}/#/studies/{study_id}")
    browser.wait_for(STUDY_PAGE_READY)
    browser.wait_for(f"!!{row}")
    browser.evaluate(f"{row}.click()")
    browser.wait_for("document.querySelector('[data-trial-dialog]').open")
    shown = browser.evaluate(
        "[...document.querySelectorAll('[data-trial-dialog] th')]"
        ".find(th => th.textContent === 'task.tip_distance')?.nextElementSibling.textContent"
    )
    assert shown is not None
    assert float(shown) == pytest.approx(first.metrics["task.tip_distance"], rel=1e-3)
    assert browser.errors == []
