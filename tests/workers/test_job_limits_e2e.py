"""A worker's job runs under limits of its own, whatever its learner does (issue 58): a
real adserver with auth on, studies of a plain ``user`` token, a real adworker with the
test plugin's ``stall`` learner, which never returns from one call (a regular
expression that backtracks for ever in C, holding the GIL; an hour's sleep) or
allocates 1 GiB. The worker stops such a job at its time or memory limit and fails its
trial naming the limit, then serves the next study; SIGTERM ends it within its stop
grace, the lease given back."""

from __future__ import annotations

import signal
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from adclient import Client
from adclient.schemas import Job, TrialState
from adclient.testing.servers import ServerProcess, make_token
from adclient.testing.workers import PATIENCE, WorkerProcess, plugin_path, wait_for
from tests.workers.robots import HALF_PI, make_job, stand_up_specs
from tests.workers.test_plugins_e2e import reach_up_study

pytestmark = pytest.mark.e2e


@pytest.fixture
def secured(plugin_site: Path, tmp_path: Path, new_sqlite_url) -> Iterator[ServerProcess]:
    """A server with auth on that has the plugin; leases last 10 minutes, so only a
    lease given back queues a trial again soon."""
    env = {**plugin_path(plugin_site), "AD_AUTH": "true", "AD_LEASE_SECONDS": "600"}
    server = ServerProcess(database_url=new_sqlite_url(), workdir=tmp_path, env=env).start()
    yield server
    server.stop()


def stall_study(way: str) -> dict[str, Any]:
    body = reach_up_study(learner="stall", options={"learner_kwargs": {"way": way}})
    body["name"] = f"stall-{way}"
    body["max_trials"] = 1
    return body


def guarded_worker(
    server: ServerProcess, plugin_site: Path, tmp_path: Path, name: str, *args: str
) -> WorkerProcess:
    token = make_token(server, "worker", name=name)
    return WorkerProcess(
        server, tmp_path, name, "--token", token, *args, env=plugin_path(plugin_site)
    )


def ended(client: Client, study_id: int) -> Any:
    """The study's first trial that has ended, if any."""
    done = (TrialState.complete, TrialState.failed)
    return next((trial for trial in client.trials(study_id) if trial.state in done), None)


@pytest.mark.slow
def test_a_learner_past_its_time_or_memory_is_failed_naming_the_limit_and_the_worker_goes_on(
    secured: ServerProcess, plugin_site: Path, tmp_path: Path
) -> None:
    user = make_token(secured, "user", name="someone")
    with Client(secured.url, user) as client:
        backtracking = client.create_study(stall_study("backtrack"))
        hoarding = client.create_study(stall_study("allocate"))
        worker = guarded_worker(
            secured, plugin_site, tmp_path, "guarded", "--job-seconds", "3",
            "--job-memory-mb", "256",
        )  # fmt: skip
        try:
            stuck = wait_for(lambda: ended(client, backtracking.id), "the backtracking trial")
            hoarded = wait_for(lambda: ended(client, hoarding.id), "the hoarding trial")
            assert worker.process.poll() is None, worker.log()  # still serving
            later = client.create_study(reach_up_study(options={"learner_kwargs": {"pose": 0}}))
            final = later.wait(poll=0.5, timeout=PATIENCE)
            assert final.n_complete == 3, [trial.message for trial in later.trials]
            assert {trial.worker_id for trial in later.trials} == {"guarded"}
        finally:
            worker.stop()
    assert stuck.state == TrialState.failed and stuck.worker_id == "guarded"
    assert "time limit of 3 s" in stuck.message and "--job-seconds" in stuck.message
    assert hoarded.state == TrialState.failed and hoarded.worker_id == "guarded"
    assert "memory" in hoarded.message and "limit of 256 MB" in hoarded.message
    assert "--job-memory-mb" in hoarded.message


@pytest.mark.slow
def test_sigterm_during_a_job_that_never_returns_ends_the_pool_within_its_grace(
    secured: ServerProcess, plugin_site: Path, tmp_path: Path
) -> None:
    """One SIGTERM to a pool whose worker holds a job asleep for an hour: that worker
    abandons the job when its grace of 1 s has run out, gives the lease back (the trial
    queued, its attempt not counted) and the pool exits 0."""
    user = make_token(secured, "user", name="someone")
    with Client(secured.url, user) as client:
        study = client.create_study(stall_study("sleep"))
        pool = guarded_worker(
            secured, plugin_site, tmp_path, "leaving", "--concurrency", "2", "--stop-grace", "1"
        )
        try:
            trial = wait_for(
                lambda: next(iter(client.trials(study.id, state="running")), None), "a lease"
            )
            pool.signal(signal.SIGTERM)
            code = pool.wait()
        finally:
            pool.stop()
        log = pool.log()
        assert code == 0, log
        assert "the stop grace of 1 s (--stop-grace) ran out" in log
        assert "lease given back" in log
        queued = client.get_trial(trial)
        assert queued.state == TrialState.queued and queued.attempts == 0, log


def test_a_job_with_a_step_budget_gets_time_for_its_steps_within_the_cap() -> None:
    """``--job-seconds`` for a job without ``train_steps``; with it, the base and each
    step's share when that is less, counting evaluation episodes (and a pruner's)."""
    from adworker.jobprocess import JOB_BASE_SECONDS, JobLimits

    limits = JobLimits(seconds=3600, step_seconds=0.05)
    job = make_job("stand-up", stand_up_specs(HALF_PI, HALF_PI), episode_steps=32)
    assert limits.seconds_for(job)[0] == 3600
    budgeted: Job = job.model_copy(
        update={"task": job.task.model_copy(update={"train_steps": 200, "eval_episodes": 3})}
    )
    seconds, why = limits.seconds_for(budgeted)
    assert seconds == pytest.approx(JOB_BASE_SECONDS + 0.05 * (200 + 3 * 32))
    assert "--job-step-seconds" in why
    huge = budgeted.model_copy(
        update={"task": budgeted.task.model_copy(update={"train_steps": 10_000_000})}
    )
    assert limits.seconds_for(huge) == (3600, "adworker --job-seconds 3600")
