"""Real adserver + real adworker processes + a managed study, over HTTP on loopback."""

from __future__ import annotations

import json
import signal
import xml.etree.ElementTree as ElementTree
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from adclient import Client
from adclient.testing.servers import ServerProcess, refused_at_start
from adclient.testing.workers import ADWORKER, PATIENCE, wait_for
from tests.workers.robots import running_trial, stand_up_study

pytestmark = pytest.mark.e2e


@pytest.fixture
def server_factory(tmp_path: Path) -> Iterator[Callable[..., ServerProcess]]:
    started: list[ServerProcess] = []

    def start(**env: str) -> ServerProcess:
        server = ServerProcess(
            database_url=f"sqlite:///{tmp_path / 'studies.db'}", workdir=tmp_path, env=env
        ).start()
        started.append(server)
        return server

    yield start
    for server in started:
        server.stop()


def children(pid: int) -> list[int]:
    """The processes whose parent is ``pid``."""
    found = []
    for entry in Path("/proc").iterdir():
        try:
            stat = (entry / "stat").read_text() if entry.name.isdigit() else ""
        except OSError:  # it ended meanwhile
            continue
        if stat and int(stat.rsplit(")", 1)[1].split()[1]) == pid:
            found.append(int(entry.name))
    return found


def test_managed_study_runs_to_completion_with_a_pool_of_workers(server_factory, workers):
    server = server_factory()
    with Client(server.url) as client:
        study = stand_up_study(client, max_trials=4, learner="fast", train_steps=256)
        pool = workers(server, "pool", "--concurrency", "2")
        final = study.wait(poll=1.0, timeout=PATIENCE)
        assert final.n_complete == 4, [t.message for t in study.trials]
        assert final.n_failed == 0
        trials = study.trials
        assert {trial.worker_id for trial in trials} <= {"pool-0", "pool-1"}
        for trial in trials:
            assert trial.value is not None and trial.value >= 0.0
            assert trial.value == trial.metrics["score_mean"]
            assert trial.metrics["train_steps"] == 256
            assert {"time_train_s", "time_evaluate_s", "score_std"} <= set(trial.metrics)
            # The secondary metrics a study may optimise: three links of 1 kg, 0.25 to
            # 0.6 m long, and motors that bend them into an arch.
            assert trial.metrics["mass"] == 3.0
            assert 0.75 <= trial.metrics["link_length"] <= 1.8
            assert trial.metrics["effort"] >= 0.0 and trial.metrics["energy"] >= 0.0
            names = {artifact.name for artifact in client.artifacts(trial)}
            assert names == {"robot.urdf", "robot.png", "curve.json", "replay.json"}
        best = study.best_trial
        assert best is not None
        urdf = ElementTree.fromstring(client.get_artifact(best, "robot.urdf"))
        assert urdf.tag == "robot"
        assert client.get_artifact(best, "robot.png").startswith(b"\x89PNG")
        curve = json.loads(client.get_artifact(best, "curve.json"))
        assert len(curve["evaluation"]) == 3
    # Its two workers are forks of its process (which imported torch, stable-baselines3
    # and PyBullet once), not fresh interpreters that import them again.
    command = Path(f"/proc/{pool.process.pid}/cmdline").read_bytes()
    forks = [Path(f"/proc/{pid}/cmdline").read_bytes() for pid in children(pool.process.pid)]
    assert forks == [command, command], forks
    pool.signal(signal.SIGTERM)
    assert pool.wait() == 0, pool.log()
    assert "jobs/min" in pool.log()


def test_killed_worker_job_is_finished_by_another_after_the_lease_expires(server_factory, workers):
    server = server_factory(AD_LEASE_SECONDS="3")
    with Client(server.url) as client:
        # A job of a few seconds, so the kill lands in the middle of it.
        study = stand_up_study(client, max_trials=1, learner="fast", train_steps=32 * 128)
        doomed = workers(server, "doomed")
        trial = wait_for(lambda: running_trial(client, study.id, "doomed"), "the first lease")
        doomed.signal(signal.SIGKILL)
        doomed.wait()
        assert client.get_trial(trial).state == "running"  # killed mid-job: nothing told
        rescuer = workers(server, "rescuer")
        final = study.wait(poll=1.0, timeout=PATIENCE)
        assert final.n_complete == 1
        finished = client.get_trial(trial)
        assert finished.state == "complete"
        assert finished.worker_id == "rescuer"
        assert finished.attempts == 2
        rescuer.signal(signal.SIGTERM)
        assert rescuer.wait() == 0


def test_sigterm_mid_job_finishes_and_reports_it_then_exits(server_factory, workers):
    server = server_factory()
    with Client(server.url) as client:
        study = stand_up_study(client, max_trials=2, learner="fast", train_steps=32 * 64)
        worker = workers(server, "polite")
        trial = wait_for(lambda: running_trial(client, study.id, "polite"), "a lease")
        worker.signal(signal.SIGTERM)
        assert worker.wait() == 0, worker.log()
        finished = client.get_trial(trial)
        assert finished.state == "complete", worker.log()
        assert finished.worker_id == "polite"
        assert client.study_info(study.id).n_complete == 1  # it took no second job


def test_second_sigterm_abandons_the_job_and_gives_the_lease_back(server_factory, workers):
    server = server_factory(AD_LEASE_SECONDS="600")  # only a release can requeue it soon
    with Client(server.url) as client:
        # A job of a few seconds (as above), so both signals land in the middle of it.
        study = stand_up_study(client, max_trials=1, learner="fast", train_steps=32 * 128)
        leaving = workers(server, "leaving")
        trial = wait_for(lambda: running_trial(client, study.id, "leaving"), "a lease")
        leaving.signal(signal.SIGTERM)
        wait_for(lambda: "finishing the current job" in leaving.log(), "the first SIGTERM")
        leaving.signal(signal.SIGTERM)  # a second one, seen apart from the first
        assert leaving.wait() == 0, leaving.log()
        assert "lease given back" in leaving.log()
        queued = client.get_trial(trial)
        assert queued.state == "queued" and queued.attempts == 0, leaving.log()
        staying = workers(server, "staying")
        final = study.wait(poll=1.0, timeout=PATIENCE)
        assert final.n_complete == 1, staying.log()
        finished = client.get_trial(trial)
        assert finished.worker_id == "staying" and finished.attempts == 1
        staying.signal(signal.SIGTERM)
        assert staying.wait() == 0


def test_adworker_leaves_a_study_of_a_learner_it_does_not_have(server_factory, workers):
    """Issue 39: adworker names the learners that load on it, so a study of another
    learner waits for a worker that has it, and says which, instead of failing its
    trials here (a function worker's failed evaluation: test_function_worker_e2e.py)."""
    server = server_factory()
    with Client(server.url) as client:
        # external: creation leaves the learner to the workers, and adworker has no such one.
        study = stand_up_study(client, max_trials=2, learner="dreamer", external=True)
        worker = workers(server, "careful", "--idle-exit", "3")
        assert worker.wait() == 0, worker.log()
        assert client.study_info(study.id).n_trials == 0
        serving = client.serving(study.id)
        assert serving is not None and (serving.serving, serving.others) == (0, 1)
        assert "with learner 'dreamer' seen in the last 90 s" in serving.text, serving.text


def test_adworker_leaves_tasks_it_does_not_have_to_other_workers(server_factory, workers):
    server = server_factory()
    with Client(server.url) as client:
        theirs = stand_up_study(client, max_trials=2, name="stand-up-v2", external=True)
        ours = stand_up_study(client, max_trials=1, learner="fast", train_steps=256)
        worker = workers(server, "choosy", "--max-jobs", "1")
        assert worker.wait() == 0, worker.log()
        assert client.study_info(ours.id).n_complete == 1
        assert client.study_info(theirs.id).n_trials == 0  # never proposed for adworker


def test_refused_token_stops_the_worker_with_a_clear_message(server_factory, workers):
    server = server_factory(AD_AUTH="true")
    worker = workers(server, "stranger", "--token", "not-a-real-token")
    assert worker.wait() == 4  # not 2, a usage error's (issue 39)
    assert "refused this worker's token" in worker.log()


def test_a_usage_error_exits_2_and_a_refused_token_does_not() -> None:
    """Issue 39: a script tells a mistyped command (2) from a refused token (4)."""
    said = refused_at_start([str(ADWORKER), "--function", "my_sim:score"], 2)
    assert "--function and --task go together" in said
