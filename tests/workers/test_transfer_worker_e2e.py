"""Issue 27, controller transfer with real ``adworker`` processes, real PyBullet and real
stable-baselines3 against a real adserver: a design starts from the checkpoint of an
evaluated design of its own tree and records it; a design of another tree never gets
a foreign one; a corrupt or missing source checkpoint means training from scratch with
the reason logged; a warm start whose lease is lost loses nothing; under ASHA a warm
design pauses and resumes with its source and warm budget."""

from __future__ import annotations

import hashlib
import io
import zipfile
from pathlib import Path

import httpx
import numpy as np
import pytest
import yaml

from adclient import Client
from adclient.pruning import CHECKPOINT_ARTIFACT
from adclient.schemas import Trial
from adclient.testing.servers import SDK_HEADERS, ServerProcess
from adclient.testing.workers import PATIENCE, WorkerProcess, plugin_path, wait_for
from tests.workers.robots import CHAIN, STAR, arm, nearest_transfer_body, run_designs, tree_design

pytestmark = [pytest.mark.e2e, pytest.mark.slow]

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def replay_size(client: Client, trial: Trial) -> int:
    """Transitions in the replay buffer of a trial's final checkpoint."""
    archive = zipfile.ZipFile(io.BytesIO(client.get_artifact(trial, CHECKPOINT_ARTIFACT)))
    with np.load(io.BytesIO(archive.read("replay_buffer.npz")), allow_pickle=False) as buffer:
        return len(buffer["observations"])


def test_a_design_starts_from_its_trees_checkpoint_and_keeps_its_replay_buffer(
    server: ServerProcess, tmp_path: Path
) -> None:
    """SAC: each tree's first design trains 256 steps from scratch; the next design of
    each tree starts from its tree's first, trains 64, and its replay buffer holds both
    designs' transitions (256 + 64)."""
    with Client(server.url) as client:
        study = client.create_study(nearest_transfer_body("sac", 256, 64))
        chain, star, chain2, star2 = run_designs(
            server,
            tmp_path,
            client,
            study.id,
            tree_design(CHAIN, 1.0),
            tree_design(STAR, 1.0),
            tree_design(CHAIN, 1.2),
            tree_design(STAR, 0.8),
        )
        for first in (chain, star):
            assert "transfer_from" not in first.info and first.metrics["train_steps"] == 256
            assert replay_size(client, first) == 256
        for warm, source in ((chain2, chain), (star2, star)):
            assert warm.info["transfer_from"] == source.id
            assert warm.metrics["train_steps"] == 64 and warm.metrics["transfer_steps"] == 64
            assert 0 < warm.metrics["transfer_distance"] < 0.2
            assert replay_size(client, warm) == 256 + 64


def test_a_corrupt_or_missing_source_checkpoint_means_training_from_scratch(
    server: ServerProcess, tmp_path: Path
) -> None:
    with Client(server.url) as client:
        study = client.create_study(nearest_transfer_body("ppo", 256, 64))
        run_designs(server, tmp_path, client, study.id, tree_design(CHAIN, 1.0))
        stored = sorted(server.artifact_dir.rglob(f"{CHECKPOINT_ARTIFACT}.*"))
        assert len(stored) == 1
        stored[0].write_bytes(b"\0" * stored[0].stat().st_size)  # corrupt, same size

        (corrupt,) = run_designs(server, tmp_path, client, study.id, tree_design(CHAIN, 1.1))
        log = (tmp_path / f"w{corrupt.id}.log").read_text()
        assert "warm start refused" in log and "training from scratch" in log, log
        assert "transfer_from" not in corrupt.info and corrupt.metrics["train_steps"] >= 256

        for path in server.artifact_dir.rglob(f"{CHECKPOINT_ARTIFACT}.*"):
            path.unlink()
        (missing,) = run_designs(server, tmp_path, client, study.id, tree_design(CHAIN, 0.9))
        log = (tmp_path / f"w{missing.id}.log").read_text()
        assert "not downloaded" in log and "training from scratch" in log, log
        assert "transfer_from" not in missing.info and missing.metrics["train_steps"] >= 256


def test_a_warm_start_whose_lease_is_lost_is_done_again_and_loses_nothing(
    server: ServerProcess, tmp_path: Path
) -> None:
    """The warm-started job is taken back (an admin's release) while it trains: its
    result is not taken, the worker leases it again, starts again from the same source
    checkpoint (unchanged) and trains its whole warm budget. The study holds these two
    designs only (max_trials), so the worker leases no third one once it is done; the
    warm budget (two PPO rollouts of 512 steps) is seconds of training against a wait
    that checks 4 times a second."""
    with Client(server.url) as client:
        study = client.create_study({**nearest_transfer_body("ppo", 256, 1024), "max_trials": 2})
        (source,) = run_designs(server, tmp_path, client, study.id, tree_design(CHAIN, 1.0))
        before = hashlib.sha256(client.get_artifact(source, CHECKPOINT_ARTIFACT)).hexdigest()
        (queued,) = client.add_trials(study.id, [{"params": tree_design(CHAIN, 1.1)}])
        worker = WorkerProcess(server, tmp_path, "w", "--no-render", "--idle-exit", "3")
        try:

            def training() -> bool:
                return client.get_trial(queued.id).state == "running"

            wait_for(training, "the warm-started trial to run")
            released = httpx.post(
                f"{server.url}/api/v1/trials/{queued.id}/release", json={}, headers=SDK_HEADERS
            )
            assert released.status_code == 200 and released.json()["state"] == "queued"

            def done_again() -> bool:
                return client.get_trial(queued.id).state == "complete"

            wait_for(done_again, "the released trial to be done again", poll=0.5)
            assert worker.wait(PATIENCE) == 0, worker.log()
        finally:
            worker.stop()
        trial = client.get_trial(queued.id)
        log = worker.log()
        assert trial.state == "complete" and trial.info["transfer_from"] == source.id, log
        assert trial.metrics["train_steps"] == 1024
        # dropped when the heartbeat saw the lease gone, else refused when it told
        assert "abandoned" in log or "result not accepted" in log, log
        assert log.count(f"trial {queued.id}: starting from trial {source.id}'s") == 2, log
        after = hashlib.sha256(client.get_artifact(source, CHECKPOINT_ARTIFACT)).hexdigest()
        assert after == before


LENGTHS = [0.5, 0.4, 0.3, 0.25, 0.22]
"""arm-length's designs in the order they run, scored 1.5, 1.2, 0.9, 0.75 and 0.66 at
every report. Under ASHA (one rung, 256 steps; halving; no bootstrap) the first,
alone at the rung, goes on and completes; each later one starts from a completed
design and pauses there (not the best of 2 or 3 values, nor in the top 2 of 4 or 5).
The fourth's value at the rung makes the second (1.2) the second best of four: it is
promoted and resumes. The last three are left paused until the budget is spent."""


def test_warm_started_trials_pause_at_asha_rungs_and_resume_with_their_warm_budget(
    plugin_server: ServerProcess, plugin_site: Path, tmp_path: Path
) -> None:
    """A warm design that pauses at an ASHA rung keeps its ``transfer_from``; promoted,
    it resumes from its own rung checkpoint, trains to its warm budget (not the
    from-scratch one) and reports at the same steps as a cold design (a tenth of the
    from-scratch budget); one left paused ends pruned when the budget is spent. The
    plugin's arm-length task scores a design by its lengths alone, so which design
    pauses and which is promoted is known whatever PPO learns."""
    train_steps, warm_steps, every = 1280, 512, 128
    options = {
        "min_resource": 256,
        "reduction_factor": 2,
        "bootstrap_count": 0,
        "max_resource": 512,
        "promotion": True,
    }
    body = yaml.safe_load((EXAMPLES / "diagonal-gesture.yaml").read_text())
    body["space"]["parts"]["link"]["length"] = {"low": 0.2, "high": 0.6}
    body["task"] = {
        "name": "arm-length",
        "learner": "ppo",
        "train_steps": train_steps,
        "eval_episodes": 1,
        "transfer": "nearest",
        "transfer_steps": warm_steps,
    }
    body["pruner"] = {"name": "asha", "options": options}
    body = {**body, "name": "transfer-asha", "max_trials": len(LENGTHS)}
    with Client(plugin_server.url) as client:
        study = client.create_study(body)
        client.add_trials(study.id, [{"params": arm(length)} for length in LENGTHS])
        env = plugin_path(plugin_site)
        worker = WorkerProcess(
            plugin_server, tmp_path, "asha", "--no-render", "--idle-exit", "5", env=env
        )
        try:
            info = study.wait(poll=1.0, timeout=PATIENCE)
            assert (info.n_complete, info.n_pruned, info.n_failed) == (2, 3, 0), worker.log()
        finally:
            worker.stop()
        first, promoted, *left = sorted(client.get_study(study.id).trials, key=lambda t: t.number)
        assert first.state == "complete" and "transfer_from" not in first.info
        assert first.value == pytest.approx(1.5) and first.metrics["train_steps"] >= train_steps
        for trial in [promoted, *left]:  # each paused at the rung with its source
            source = client.get_trial(trial.info["transfer_from"])
            assert source.state == "complete" and source.number < trial.number
            assert trial.checkpoint is not None and trial.checkpoint.rung == 256
            assert trial.checkpoint.metrics["transfer_steps"] == warm_steps
            assert trial.checkpoint.budget == warm_steps
        assert promoted.info["transfer_from"] == first.id  # the only complete design then
        assert promoted.state == "complete" and promoted.value == pytest.approx(1.2)
        assert promoted.metrics["resumed_from_step"] == 256
        assert warm_steps <= promoted.metrics["train_steps"] < train_steps
        assert promoted.metrics["transfer_steps"] == warm_steps
        for trial in left:
            assert trial.state == "pruned" and "budget" in (trial.message or ""), trial
        for trial in [first, promoted, *left]:
            steps = [report.step for report in client.reports(trial)]
            assert steps and all(step % every == 0 for step in steps), (trial.number, steps)
        # resumed at the rung, it reports on at the cold designs' steps
        assert [report.step for report in client.reports(promoted)][:3] == [128, 256, 384]
