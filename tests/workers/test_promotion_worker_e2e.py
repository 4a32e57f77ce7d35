"""ASHA promotion with real ``adworker`` processes, real PyBullet and real
stable-baselines3 against a real adserver: trials stopped at a rung pause with their SB3
checkpoint, the ones promoted later resume from it (training goes on from the rung's
step, not from 0), also after the resumed job's lease is lost, and the ones still
paused when the budget is spent end pruned."""

from __future__ import annotations

import json
from pathlib import Path

import httpx
import pytest

from adclient import Client
from adclient.schemas import Trial
from adclient.testing.servers import SDK_HEADERS, ServerProcess
from adclient.testing.workers import PATIENCE, WorkerProcess, wait_for
from tests.workers.robots import RUNG, promoting

pytestmark = [pytest.mark.e2e, pytest.mark.slow]


def check_resumed(client: Client, trial: Trial, train_steps: int) -> None:
    """Its checkpoint is the SB3 state at the rung and its training went on from there."""
    assert trial.state == "complete" and trial.checkpoint is not None
    assert trial.checkpoint.step == RUNG and trial.checkpoint.rung == RUNG
    assert trial.metrics["resumed_from_step"] == RUNG
    assert trial.metrics["train_steps"] >= train_steps
    # Worker time is the whole trial's: the attempt before the pause and the resumed one.
    assert trial.metrics["time_total_s"] > trial.checkpoint.metrics["time_total_s"]
    curve = json.loads(client.get_artifact(trial, "curve.json"))
    # Episodes of the resumed training only, counted on from the checkpoint's step: a
    # learner that started over would have its first episodes at 32, 64, ... steps.
    assert curve["train"] and min(point["steps"] for point in curve["train"]) > RUNG
    steps = [report.step for report in client.reports(trial)]
    assert steps[:2] == [128, RUNG] and steps[2] == RUNG + 128, steps
    archive = client.get_artifact(trial, "checkpoint.zip")
    assert archive[:2] == b"PK"


def finished(client: Client, study_id: int, worker: WorkerProcess) -> list[Trial]:
    info = client.get_study(study_id).wait(poll=1.0, timeout=PATIENCE)
    assert info.n_complete + info.n_pruned == 4 and info.n_failed == 0, worker.log()
    return client.get_study(study_id).trials


TRAIN_STEPS = {"ppo": 1024, "sac": 512}
"""Budgets past the rung's next report (RUNG + 128): PPO's rollouts of 512 steps, the
pause at 256 inside one; SAC's updates (one per step, the cost of its training) from 128
steps on (learning_starts is a quarter of the budget), so its checkpoint at the rung
holds a trained model and a replay buffer in use."""


@pytest.mark.parametrize("learner", ["ppo", "sac"])
def test_paused_trials_are_promoted_and_resume_from_their_checkpoint(
    server: ServerProcess, tmp_path: Path, learner: str
) -> None:
    train_steps = TRAIN_STEPS[learner]
    with Client(server.url) as client:
        study = client.create_study(promoting(learner, train_steps))
        worker = WorkerProcess(server, tmp_path, learner, "--no-render", "--idle-exit", "5")
        try:
            trials = finished(client, study.id, worker)
            resumed = [t for t in trials if "resumed_from_step" in t.metrics]
            assert resumed, worker.log()
            for trial in resumed:
                check_resumed(client, trial, train_steps)
            left = [t for t in trials if t.state == "pruned"]
            for trial in left:  # paused at the rung until the budget was spent
                assert trial.checkpoint is not None and "budget" in (trial.message or "")
                assert trial.value == client.reports(trial)[-1].value
            assert "resuming from step 256" in worker.log()
        finally:
            worker.stop()


def test_a_resumed_job_whose_lease_is_lost_resumes_from_the_same_checkpoint(
    server: ServerProcess, tmp_path: Path
) -> None:
    """The first resumed job is taken back (an admin's release) while it trains: the
    worker drops it unreported, leases the trial again and resumes it from the same
    checkpoint, to the end of the budget."""
    # A resumed job long enough to be caught running: 1,792 steps past the rung, 14
    # reports (each an evaluation episode), seconds of training against a 0.25 s poll
    # (each poll lists the study's trials: 20 a second cost the server more than the
    # training).
    train_steps = 2048
    with Client(server.url) as client:
        study = client.create_study(promoting("ppo", train_steps))
        worker = WorkerProcess(server, tmp_path, "ppo", "--no-render", "--idle-exit", "5")
        try:

            def resuming() -> Trial | None:
                running = [t for t in study.trials if t.state == "running" and t.checkpoint]
                return running[0] if running else None

            trial = wait_for(resuming, "a promoted trial to be resumed", poll=0.25)
            assert isinstance(trial, Trial)
            released = httpx.post(
                f"{server.url}/api/v1/trials/{trial.id}/release", json={}, headers=SDK_HEADERS
            )
            assert released.status_code == 200 and released.json()["state"] == "queued"
            trials = finished(client, study.id, worker)
            again = next(t for t in trials if t.id == trial.id)
            check_resumed(client, again, train_steps)
            log = worker.log()
            assert "lease lost" in log and "abandoned" in log, log
            label = f"trial {trial.id}: resuming from step {RUNG}"
            assert log.count(label) >= 2, log
        finally:
            worker.stop()
