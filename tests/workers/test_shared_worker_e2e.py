"""Issue 38, a shared controller with real ``adworker`` processes, real PyBullet and real
stable-baselines3 against a real adserver: every design, the first of a new tree
included, starts from the study's current version and records it; two workers at once
lose no update; a version that does not load means the study's initial weights with
the reason logged. (The server's rules, and merging updates made at once, are
tests/service/test_shared_controller.py's.)"""

from __future__ import annotations

import itertools
from pathlib import Path
from typing import Any

import pytest
import yaml

from adclient import Client
from adclient.schemas import SHARED_ARTIFACT
from adclient.testing.servers import ServerProcess
from adclient.testing.workers import WorkerProcess, plugin_path, stop_workers
from adworker import shared_weights
from tests.workers.robots import CHAIN, STAR, arm, run_designs, tree_design, two_tree_body

pytestmark = [pytest.mark.e2e, pytest.mark.slow]

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
BUDGET, WARM = 256, 128


def study_body(max_trials: int = 20) -> dict[str, Any]:
    task = {
        "name": "lift-highest",
        "learner": "ppo",
        "train_steps": BUDGET,
        "eval_episodes": 1,
        "transfer": "shared",
        "transfer_steps": WARM,
    }
    return two_tree_body(task, "shared", max_trials)


def test_every_design_starts_from_the_shared_controller_and_updates_it(
    server: ServerProcess, tmp_path: Path
) -> None:
    """The study's first design trains its full budget from the initial weights and
    makes version 1; the next, the first of another tree, starts from version 1 (one set
    of weights drives three joints where it was trained on two), trains the warm budget
    and makes version 2; and so on. Each version's weights are the uploaded update of
    the trial that made it, and they differ from the one before."""
    with Client(server.url) as client:
        study = client.create_study(study_body())
        trials = run_designs(
            server,
            tmp_path,
            client,
            study.id,
            tree_design(CHAIN, 1.0),
            tree_design(STAR, 1.0),
            tree_design(CHAIN, 1.2),
            tree_design(STAR, 0.8),
        )
        first = trials[0]
        assert first.metrics["shared_from"] == 0 and first.metrics["train_steps"] >= BUDGET
        assert first.info["shared"] == {"from": None, "version": 1}
        for version, trial in enumerate(trials[1:], start=1):
            assert trial.metrics["shared_from"] == version, trial.metrics
            assert trial.metrics["train_steps"] == WARM, trial.metrics
            assert trial.info["shared"] == {"from": version, "version": version + 1}
        current = client.shared_controller(study.id)
        assert current is not None and (current.version, current.trial_id) == (4, trials[-1].id)
        updates = [
            shared_weights.decode(client.get_artifact(trial, SHARED_ARTIFACT)) for trial in trials
        ]
        names = set(updates[0])
        assert all(set(update) == names for update in updates)
        assert all(
            any((before[name] != after[name]).any() for name in names)
            for before, after in itertools.pairwise(updates)
        )


def test_two_workers_at_once_lose_no_update(server: ServerProcess, tmp_path: Path) -> None:
    """Six designs, two workers: every complete design made a version, the versions run
    1 to 6 with none skipped, and each design started from a version made before it."""
    with Client(server.url) as client:
        study = client.create_study(study_body(max_trials=6))
        workers = [
            WorkerProcess(server, tmp_path, f"w{k}", "--no-render", "--idle-exit", "5")
            for k in range(2)
        ]
        try:
            for worker in workers:
                assert worker.wait() == 0, worker.log()
        finally:
            stop_workers(workers)
        trials = client.trials(study.id)
        logs = "\n".join(worker.log() for worker in workers)
        assert len(trials) == 6 and all(t.state == "complete" for t in trials), logs
        made = sorted(trial.info["shared"]["version"] for trial in trials)
        assert made == [1, 2, 3, 4, 5, 6], logs
        for trial in trials:
            started = trial.metrics["shared_from"]
            assert started < trial.info["shared"]["version"]
        current = client.shared_controller(study.id)
        assert current is not None and current.version == 6


def test_a_version_that_does_not_load_means_the_initial_weights(
    server: ServerProcess, tmp_path: Path
) -> None:
    """The current version's file is corrupted on the server: the next design logs why,
    starts from the study's initial weights for the full budget, and its update becomes
    the next version in place of the broken one."""
    with Client(server.url) as client:
        study = client.create_study(study_body())
        (first,) = run_designs(server, tmp_path, client, study.id, tree_design(CHAIN, 1.0))
        stored = sorted(server.artifact_dir.rglob(f"{SHARED_ARTIFACT}.*"))
        assert len(stored) == 1
        stored[0].write_bytes(b"\0" * stored[0].stat().st_size)  # corrupt, same size

        (second,) = run_designs(server, tmp_path, client, study.id, tree_design(STAR, 1.0))
        log = (tmp_path / f"w{second.id}.log").read_text()
        assert "shared controller version 1 does not load" in log, log
        assert second.metrics["shared_from"] == 0 and second.metrics["train_steps"] >= BUDGET
        assert second.info["shared"] == {"from": 1, "version": 2}
        current = client.shared_controller(study.id)
        assert current is not None and current.trial_id == second.id
        assert shared_weights.decode(client.get_artifact(second, SHARED_ARTIFACT))
        assert first.info["shared"]["version"] == 1


def test_a_design_the_shared_controller_scores_poorly_is_screened_before_training(
    plugin_server: ServerProcess, plugin_site: Path, tmp_path: Path
) -> None:
    """With a pruner, a design that starts from a version first reports the shared
    controller's score on it, untrained, at step 0; the median pruner stops one that
    scores below the complete designs' there, before any training, and the proposer is
    told that score. arm-length scores a design 3 x its link length whatever the
    controller, so which design is screened out is known: the first has no version to
    be scored by, the second (1.65) has no complete design's step-0 score to be judged
    against, the third (0.9) is below the second's and stops at step 0, the fourth
    (1.74) trains."""
    body = yaml.safe_load((EXAMPLES / "diagonal-gesture.yaml").read_text())
    body["space"]["parts"]["link"]["length"] = {"low": 0.2, "high": 0.6}
    body["task"] = {
        "name": "arm-length",
        "learner": "ppo",
        "train_steps": BUDGET,
        "eval_episodes": 1,
        "transfer": "shared",
        "transfer_steps": WARM,
    }
    options = {"n_startup_trials": 1, "n_warmup_steps": 0}
    body["pruner"] = {"name": "median", "options": options, "report_every": BUDGET}
    lengths = [0.5, 0.55, 0.3, 0.58]
    with Client(plugin_server.url) as client:
        study = client.create_study({**body, "name": "screening", "max_trials": len(lengths)})
        client.add_trials(study.id, [{"params": arm(length)} for length in lengths])
        worker = WorkerProcess(
            plugin_server,
            tmp_path,
            "screen",
            "--no-render",
            "--max-jobs",
            str(len(lengths)),
            env=plugin_path(plugin_site),
        )
        try:
            assert worker.wait() == 0, worker.log()
        finally:
            worker.stop()
        first, second, poor, fourth = sorted(client.trials(study.id), key=lambda t: t.number)
        assert [report.step for report in client.reports(first)] == []
        for trial, value in ((second, 1.65), (fourth, 1.74)):
            assert trial.state == "complete", worker.log()
            assert [(r.step, r.value) for r in client.reports(trial)] == [(0, pytest.approx(value))]
            assert trial.metrics["train_steps"] == WARM
        assert poor.state == "pruned" and poor.value == pytest.approx(0.9), worker.log()
        assert poor.metrics["train_steps"] == 0 and "shared" not in poor.info
        assert [report.step for report in client.reports(poor)] == [0]
        current = client.shared_controller(study.id)
        assert current is not None and (current.version, current.trial_id) == (3, fourth.id)
