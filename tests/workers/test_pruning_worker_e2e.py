"""Pruning with real ``adworker`` processes and a real adserver: a function worker's
``job.report`` and the learners' evaluations while they train reach the server, and a
trial the study's pruner stops ends ``pruned`` with its last value, no further steps."""

from __future__ import annotations

from pathlib import Path

import httpx
import pytest

from adclient import Client
from adclient.testing.servers import SDK_HEADERS, ServerProcess
from adclient.testing.workers import PATIENCE, WorkerProcess, wait_for
from tests.workers.robots import stand_up

pytestmark = pytest.mark.e2e

CURVES = '''
import time

def curve(job):
    """Even trials learn (10 per step), odd ones do not (0): odd ones are pruned at their
    first report once one even trial is complete (median, one startup trial)."""
    slope = 10.0 if job.number % 2 == 0 else 0.0
    for step in range(1, 6):
        job.report(step, slope * step)
    return slope * 5


def slow(job):
    """Reports, pauses (the test takes the lease away meanwhile), reports again."""
    job.report(1, 1.0)
    time.sleep(2)
    job.report(2, 2.0)
    return 2.0
'''


def test_a_function_workers_trials_are_pruned_by_the_median(
    server: ServerProcess, tmp_path: Path
) -> None:
    app = tmp_path / "app"
    app.mkdir()
    (app / "curves.py").write_text(CURVES)
    args = ["--app-dir", str(app), "--function", "curves:curve", "--task", "curve"]
    worker = WorkerProcess(server, tmp_path, "fn", *args, "--max-jobs", "4")
    try:
        with Client(server.url) as client:
            study = client.create_study(
                name="curves",
                space={"type": "box", "params": [{"name": "x", "low": 0, "high": 1}]},
                proposer={"name": "random"},
                pruner={"name": "median", "options": {"n_startup_trials": 1}},
                task={"name": "curve", "external": True},
                max_trials=4,
            )
            info = study.wait(poll=0.2, timeout=PATIENCE)
            assert (info.n_complete, info.n_pruned, info.n_failed) == (2, 2, 0), worker.log()
            for trial in study.trials:
                reports = [(r.step, r.value) for r in client.reports(trial)]
                if trial.number % 2 == 0:
                    assert trial.state == "complete" and trial.value == 50.0
                    assert reports == [(s, 10.0 * s) for s in range(1, 6)]
                else:  # stopped at its first report: no later step was run
                    assert trial.state == "pruned" and trial.value == 0.0
                    assert reports == [(1, 0.0)]
                    assert trial.metrics["train_steps"] == 1.0
            assert worker.wait() == 0, worker.log()
            assert "pruned at step 1" in worker.log()
    finally:
        worker.stop()


def test_a_report_after_the_lease_is_lost_cancels_the_job(
    server: ServerProcess, tmp_path: Path
) -> None:
    """The trial is taken back (an admin's release) while the function runs: its next
    report is a 409, the worker drops the job unreported, then leases the trial again
    and finishes it; the repeated reports are harmless."""
    app = tmp_path / "app"
    app.mkdir()
    (app / "curves.py").write_text(CURVES)
    args = ["--app-dir", str(app), "--function", "curves:slow", "--task", "slow"]
    worker = WorkerProcess(server, tmp_path, "slow", *args, "--max-jobs", "1")
    try:
        with Client(server.url) as client:
            study = client.create_study(
                name="slow",
                space={"type": "box", "params": [{"name": "x", "low": 0, "high": 1}]},
                proposer={"name": "random"},
                pruner={"name": "median"},
                task={"name": "slow", "external": True},
                max_trials=1,
            )
            wait_for(lambda: study.trials, "the trial to be leased")
            trial = study.trials[0]
            wait_for(lambda: client.reports(trial), "the first report")
            released = httpx.post(
                f"{server.url}/api/v1/trials/{trial.id}/release", json={}, headers=SDK_HEADERS
            )
            assert released.status_code == 200 and released.json()["state"] == "queued"
            info = study.wait(poll=0.2, timeout=PATIENCE)
            assert info.n_complete == 1, worker.log()
            assert worker.wait() == 0, worker.log()
            log = worker.log()
            assert "lease lost" in log and "abandoned" in log, log
            assert [(r.step, r.value) for r in client.reports(trial)] == [(1, 1.0), (2, 2.0)]
            assert client.get_trial(trial).value == 2.0
    finally:
        worker.stop()


@pytest.mark.parametrize("learner", ["ppo", "fast"])
def test_learners_report_while_training_and_stop_when_told(
    server: ServerProcess, tmp_path: Path, learner: str
) -> None:
    """Every trial of a first ASHA rung that needs more values than a study can have
    (bootstrap_count) is stopped there: the learner stops training at the first report
    past 128 steps and the trial is told pruned with the score it reported."""
    pruner = {
        "name": "asha",
        "options": {"min_resource": 128, "bootstrap_count": 1000},
        "report_every": 64,
    }
    with Client(server.url) as client:
        study = client.create_study(stand_up(learner, 1024, pruner))
        worker = WorkerProcess(server, tmp_path, learner, "--max-jobs", "2", "--no-render")
        try:
            info = study.wait(poll=0.2, timeout=PATIENCE)
            assert (info.n_pruned, info.n_complete, info.n_failed) == (2, 0, 0), worker.log()
            for trial in study.trials:
                reports = [(r.step, r.value) for r in client.reports(trial)]
                assert [step for step, _ in reports] == [64, 128], reports
                assert trial.value == reports[-1][1]
                assert trial.metrics["train_steps"] == 128.0
            assert worker.wait() == 0, worker.log()
        finally:
            worker.stop()
