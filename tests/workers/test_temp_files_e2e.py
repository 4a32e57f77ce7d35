"""Issue 29, a worker leaves nothing in the temporary folder, with real ``adworker``
processes, real PyBullet and real stable-baselines3 against a real adserver: not after a
batch of SB3 jobs (from scratch, warm-started, paused and resumed), not when SIGTERM or
SIGINT stops it mid-job, and what a worker killed outright (SIGKILL) left is removed by
the next one to start. Each worker's ``TMPDIR`` is a fresh folder of its own, so the
count is exact."""

from __future__ import annotations

import getpass
import signal
from pathlib import Path

import pytest

from adclient import Client
from adclient.schemas import Trial
from adclient.testing.servers import ServerProcess
from adclient.testing.workers import WorkerProcess, wait_for
from tests.workers.robots import CHAIN, nearest_transfer_body, promoting, stand_up, tree_design

pytestmark = [pytest.mark.e2e, pytest.mark.slow]


def temporary_folder(tmp_path: Path) -> Path:
    folder = tmp_path / "tmp"
    folder.mkdir()
    return folder


TORCH_CACHE = f"torchinductor_{getpass.getuser()}"
"""torch's compile cache, made (empty) by importing its optimizers: one folder per user,
shared by all their processes and jobs, so not a job's leftover; its files would be."""


def left_in(folder: Path) -> list[str]:
    """Everything under ``folder`` but torch's empty cache folder, for an assertion's
    message."""
    return sorted(
        str(path.relative_to(folder)) for path in folder.rglob("*") if path.name != TORCH_CACHE
    )


def worker_in(
    server: ServerProcess, tmp_path: Path, tmp: Path, worker_id: str, *args: str
) -> WorkerProcess:
    return WorkerProcess(server, tmp_path, worker_id, *args, env={"TMPDIR": str(tmp)})


def running(client: Client, study_id: int) -> Trial | None:
    trials = client.trials(study_id, state="running")
    return trials[0] if trials else None


def test_a_batch_of_sb3_jobs_leaves_nothing_in_the_temporary_folder(
    server: ServerProcess, tmp_path: Path
) -> None:
    """PPO from scratch, warm-started from another trial's checkpoint, paused at an ASHA
    rung and resumed from its checkpoint: one worker, and its temporary folder is as
    empty after it as before."""
    tmp = temporary_folder(tmp_path)
    with Client(server.url) as client:
        transfer = client.create_study({**nearest_transfer_body("ppo", 256, 64), "max_trials": 2})
        added = client.add_trials(
            transfer.id, [{"params": tree_design(CHAIN, angle)} for angle in (1.0, 1.1)]
        )
        asha = client.create_study(promoting("ppo", 512))
        worker = worker_in(server, tmp_path, tmp, "batch", "--idle-exit", "5")
        try:
            assert worker.wait() == 0, worker.log()
        finally:
            worker.stop()
        log = worker.log()
        warm = client.get_trial(added[1].id)
        assert warm.state == "complete" and warm.info["transfer_from"] == added[0].id, log
        trials = client.get_study(asha.id).trials
        assert {trial.state for trial in trials} <= {"complete", "pruned"}, log
        assert any("resumed_from_step" in trial.metrics for trial in trials), log
    assert not left_in(tmp), f"left behind: {left_in(tmp)}\n{log}"


@pytest.mark.parametrize("signals", [("SIGTERM",), ("SIGINT", "SIGINT")])
def test_a_signal_mid_job_leaves_nothing_in_the_temporary_folder(
    server: ServerProcess, tmp_path: Path, signals: tuple[str, ...]
) -> None:
    """Stopped while PPO trains (it has reported): one signal finishes and reports the
    job, two abandon it and give its lease back; either way its folders go with it. The
    signals follow the first report (64 steps) at once, so 1,024 steps (two rollouts of
    512) leave seconds of training to land in."""
    tmp = temporary_folder(tmp_path)
    never = {"name": "median", "options": {"n_startup_trials": 1000}, "report_every": 64}
    with Client(server.url) as client:
        study = client.create_study({**stand_up("ppo", 1024, never), "max_trials": 1})
        worker = worker_in(server, tmp_path, tmp, "stopped")
        try:
            trial = wait_for(lambda: running(client, study.id), "a lease")
            assert isinstance(trial, Trial)
            wait_for(lambda: client.reports(trial), "a report while it trains")
            for number, name in enumerate(signals):
                if number:
                    wait_for(lambda: "finishing the current job" in worker.log(), name)
                worker.signal(getattr(signal, name))
            assert worker.wait() == 0, worker.log()
        finally:
            worker.stop()
        log = worker.log()
        after = client.get_trial(trial.id)
        if len(signals) == 1:
            assert after.state == "complete" and after.worker_id == "stopped", log
        else:
            assert after.state == "queued" and after.attempts == 0, log
            assert "lease given back" in log
    assert not left_in(tmp), f"left behind: {left_in(tmp)}\n{log}"


def test_the_folder_of_a_killed_worker_is_removed_by_the_next_one(
    server: ServerProcess, tmp_path: Path
) -> None:
    """SIGKILL leaves no chance to clean up: the next worker on the same temporary
    folder removes what a dead worker left, and keeps its own until it stops."""
    tmp = temporary_folder(tmp_path)
    with Client(server.url) as client:
        body = stand_up("fast", 32 * 256, {"name": "none"})
        study = client.create_study({**body, "max_trials": 1})
        doomed = worker_in(server, tmp_path, tmp, "doomed", "--no-render")
        try:
            wait_for(lambda: running(client, study.id), "a lease")
            wait_for(lambda: list(tmp.glob("*/*/robot.urdf")), "the job's files")
            doomed.signal(signal.SIGKILL)
            doomed.wait()
        finally:
            doomed.stop()
        left = left_in(tmp)
        assert left, "a worker killed mid-job had nothing in its temporary folder"
        # The trial stays leased to the dead worker: the next one finds no work.
        after = worker_in(server, tmp_path, tmp, "after", "--idle-exit", "1")
        try:
            assert after.wait() == 0, after.log()
        finally:
            after.stop()
    assert not left_in(tmp), f"left behind: {left_in(tmp)} ({left} before it)\n{after.log()}"


def test_a_worker_stopped_by_its_harness_leaves_nothing(
    server: ServerProcess, tmp_path: Path
) -> None:
    """``WorkerProcess.stop``, as the benchmarks and fixtures end their workers, stops an
    idle worker after its study is done by a signal it handles (exit 0, not SIGKILL), so
    the folder its job made goes with it."""
    tmp = temporary_folder(tmp_path)
    with Client(server.url) as client:
        study = client.create_study({**stand_up("fast", 256, {"name": "none"}), "max_trials": 1})
        worker = worker_in(server, tmp_path, tmp, "harnessed", "--no-render")
        try:
            wait_for(lambda: client.study_info(study.id).n_complete == 1, "the design")
            assert left_in(tmp), "the worker's job made no folder to remove"
        finally:
            worker.stop()
        assert worker.process.poll() == 0, worker.log()
    assert not left_in(tmp), f"left behind: {left_in(tmp)}\n{worker.log()}"
