"""A worker older than its server: a real adserver process and an in-process worker whose
schemas lack the task's newest field (``shared_carries``), as an adworker released
before it has. It runs every job that leaves the field at its default, and fails a job
that uses it, saying why, without stopping (docs/worker.md, "Workers older than the
server")."""

from __future__ import annotations

from pathlib import Path

import pytest
from pydantic import ConfigDict, create_model

import adclient.calls
from adclient import Client
from adclient.schemas import Job, TaskConfig, TrialState
from adclient.testing.servers import ServerProcess
from adworker.worker import EXIT_OK, Worker, WorkerConfig
from tests.workers.robots import stand_up_study

pytestmark = pytest.mark.e2e

NEWEST_FIELD = "shared_carries"


def older_job_schema(missing: str) -> type[Job]:
    """``Job`` as a worker from before ``task.<missing>`` reads it: the same strict task
    schema without that field."""
    fields = {
        name: (info.annotation, info)
        for name, info in TaskConfig.model_fields.items()
        if name != missing
    }
    assert len(fields) == len(TaskConfig.model_fields) - 1
    older_task = create_model(  # type: ignore[call-overload]
        "OlderTaskConfig", __config__=ConfigDict(extra="forbid"), **fields
    )
    return create_model(  # type: ignore[call-overload, no-any-return]
        "OlderJob", __base__=Job, __module__=Job.__module__, task=(older_task, ...)
    )


def run_older_worker(url: str) -> Worker:
    worker = Worker(
        WorkerConfig(server=url, worker_id="older", poll=0.2, idle_exit=1.5, render=False)
    )
    assert worker.run() == EXIT_OK
    return worker


def test_an_older_worker_runs_jobs_it_can_read_and_fails_the_others_saying_why(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(adclient.calls, "Job", older_job_schema(NEWEST_FIELD))
    server = ServerProcess(
        database_url=f"sqlite:///{tmp_path / 'studies.db'}", workdir=tmp_path
    ).start()
    try:
        with Client(server.url) as client:
            plain = stand_up_study(client, max_trials=2, learner="fast", train_steps=256)
            worker = run_older_worker(server.url)
            assert (worker.rates.jobs, worker.rates.failed) == (2, 0)
            trials = plain.trials
            assert [t.state for t in trials] == [TrialState.complete] * 2, [
                t.message for t in trials
            ]

            # a newer study's design, queued so it is leased first, then a plain study's
            newer = stand_up_study(
                client, max_trials=1, learner="fast", train_steps=256, **{NEWEST_FIELD: "critic"}
            )
            client.add_trials(newer.id, [{"params": trials[0].params}])
            later = stand_up_study(client, max_trials=1, learner="fast", train_steps=256)
            worker = run_older_worker(server.url)
            assert (worker.rates.jobs, worker.rates.failed) == (2, 1)
            [trial] = newer.trials
            assert trial.state == TrialState.failed
            assert trial.worker_id == "older"
            assert "cannot read this job" in (trial.message or "")
            assert f"task.{NEWEST_FIELD}" in (trial.message or "")
            assert "upgrade the worker" in (trial.message or "")
            # it went on leasing after refusing
            assert [t.state for t in later.trials] == [TrialState.complete]
            assert [t.state for t in plain.trials] == [TrialState.complete] * 2
    finally:
        server.stop()
