"""``adworker --function module:callable --task NAME`` against a real adserver: a plain
callable scores a box study and a design study of external tasks, through adworker's
own loop (leases, concurrency, artifacts, failures, SIGTERM), and leaves the studies of
other tasks alone."""

from __future__ import annotations

import signal
from pathlib import Path
from typing import Any

import pytest
import yaml

from adclient import Client
from adclient.testing.servers import ServerProcess
from adclient.testing.workers import PATIENCE, WorkerProcess, stop_workers, wait_for

pytestmark = pytest.mark.e2e

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
SCORER = '''
def quadratic(job):
    """A box study: params in, a value and a metric out, a curve and a file on the side."""
    x = job.params["x"]
    if job.number == 1:
        raise ValueError(f"trial number one refuses x={x}")
    for step in range(3):
        job.report(step, x * step)
    (job.artifact_dir / "note.txt").write_text(f"x={x} seed={job.seed}")
    return {"value": (x - 1.0) ** 2, "x_squared": x * x}


def arm_length(job):
    """A design study: the decoded design and its URDF, as a simulator would read them."""
    assert job.urdf_path.read_text().startswith("<?xml")
    return sum(link.length for link in job.design.links) + job.options["offset"]
'''


@pytest.fixture
def app_dir(tmp_path: Path) -> Path:
    folder = tmp_path / "app"
    folder.mkdir()
    (folder / "scorer.py").write_text(SCORER)
    return folder


def design_study(**task: Any) -> dict[str, Any]:
    body = yaml.safe_load((EXAMPLES / "diagonal-gesture.yaml").read_text())
    body["space"]["parts"]["link"]["length"] = {"low": 0.2, "high": 0.6}
    body["proposer"] = {"name": "random", "seed": 2}
    return {**body, "name": "arm", "task": task, "max_trials": 2}


def test_function_workers_serve_their_tasks_only(
    server: ServerProcess, app_dir: Path, tmp_path: Path
) -> None:
    started: list[WorkerProcess] = []

    def worker(worker_id: str, *args: str) -> WorkerProcess:
        started.append(WorkerProcess(server, tmp_path, worker_id, "--app-dir", str(app_dir), *args))
        return started[-1]

    try:
        with Client(server.url) as client:
            box = client.create_study(
                name="box",
                direction="minimize",
                space={"type": "box", "params": [{"name": "x", "low": -2, "high": 2}]},
                proposer={"name": "random", "seed": 1},
                task={"name": "quadratic", "external": True, "seed": 7},
                max_trials=4,
            )
            arm = client.create_study(
                design_study(name="arm-length", external=True, options={"offset": 10.0})
            )
            other = client.create_study(
                yaml.safe_load((EXAMPLES / "stand-up.yaml").read_text()) | {"max_trials": 1}
            )
            quadratic = ["--function", "scorer:quadratic", "--task", "quadratic"]
            pool = worker("pool", *quadratic, "--concurrency", "2")
            single = worker("single", "--function", "scorer:arm_length", "--task", "arm-length")

            done = box.wait(poll=0.2, timeout=PATIENCE)
            assert (done.n_complete, done.n_failed) == (3, 1), pool.log()
            for trial in box.trials:
                assert trial.worker_id in {"pool-0", "pool-1"}
                x = trial.params["x"]
                if trial.number == 1:
                    assert trial.state == "failed"
                    assert (trial.message or "").startswith("ValueError: trial number one")
                    continue
                assert trial.value == pytest.approx((x - 1.0) ** 2)
                assert trial.metrics["x_squared"] == pytest.approx(x * x)
                assert trial.metrics["time_total_s"] >= 0
                assert client.get_artifact(trial, "note.txt") == f"x={x} seed=7".encode()
                curve = client.trial_curve(trial)  # the SDK reads what the worker wrote
                assert [(p.steps, p.score) for p in curve.train] == [(0, 0.0), (1, x), (2, 2 * x)]

            assert arm.wait(poll=0.2, timeout=PATIENCE).n_complete == 2, single.log()
            for trial in arm.trials:
                length = sum(trial.params[f"{link}.length"] for link in "abc")
                assert trial.value == pytest.approx(length + 10.0)
                assert trial.worker_id == "single"
                assert {a.name for a in client.artifacts(trial)} == {"robot.urdf"}

            assert client.study_info(other.id).n_trials == 0, "a function leased stand-up"
            for process in (pool, single):
                process.signal(signal.SIGTERM)
                assert process.wait() == 0, process.log()
    finally:
        stop_workers(started)


def test_sigterm_lets_a_function_job_finish_and_report(
    server: ServerProcess, tmp_path: Path
) -> None:
    app = tmp_path / "slow"
    app.mkdir()
    (app / "slow.py").write_text(
        "import time\n\ndef score(job):\n    time.sleep(2)\n    return job.params['x']\n"
    )
    with Client(server.url) as client:
        study = client.create_study(
            name="slow",
            space={"type": "box", "params": [{"name": "x", "low": 0, "high": 1}]},
            proposer={"name": "random"},
            task={"name": "slow", "external": True},
            max_trials=3,
        )
        function = ["--app-dir", str(app), "--function", "slow:score", "--task", "slow"]
        worker = WorkerProcess(server, tmp_path, "slow", *function)
        try:
            wait_for(lambda: client.study_info(study.id).n_running, "a lease")
            worker.signal(signal.SIGTERM)
            assert worker.wait() == 0, worker.log()
        finally:
            worker.stop()
        info = client.study_info(study.id)
        assert (info.n_complete, info.n_running) == (1, 0), worker.log()


def test_a_function_that_does_not_import_stops_the_worker_at_start(
    server: ServerProcess, tmp_path: Path
) -> None:
    worker = WorkerProcess(
        server, tmp_path, "typo", "--function", "no_such_module:score", "--task", "x"
    )
    assert worker.wait() == 3
    assert "cannot start: ModuleNotFoundError" in worker.log()
