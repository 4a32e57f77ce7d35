"""Issue 58's noisy neighbour: on one real server with auth on, a plain ``user`` token
sends the worst of the issue's findings at once (creations of random 32-link trees
abandoned after a second, an entity bomb, a learner that would hold a worker for hours,
leases of another user's tasks, uploads past its storage quota, asks of a template whose
URDFs are megabytes), while another user's ordinary study is read, leased, told and
worked by a real adworker. That study's reads and leases stay within 2x of their quiet
latency (medians of alternating quiet and noisy blocks in the same run), its trials
complete, and nothing of it reaches the noisy user (adclient.testing.neighbours)."""

from __future__ import annotations

from pathlib import Path

import pytest

from adclient.testing.neighbours import (
    ORDINARY_TASK,
    client,
    measure,
    ordinary_studies,
)
from adclient.testing.servers import ServerProcess, make_token
from adclient.testing.workers import WorkerProcess, stop_workers

pytestmark = [pytest.mark.e2e, pytest.mark.slow, pytest.mark.alone]

SCORER = "def score(job):\n    return job.params['x']\n"


def test_an_ordinary_study_keeps_its_pace_beside_the_worst_a_user_may_send(
    tmp_path: Path, new_sqlite_url: object
) -> None:
    server = ServerProcess(
        database_url=new_sqlite_url(),  # type: ignore[operator]
        workdir=tmp_path,
        env={"AD_AUTH": "1", "AD_OWNER_STORAGE_BYTES": "20000000"},
    ).start()
    app = tmp_path / "app"
    app.mkdir()
    (app / "scorer.py").write_text(SCORER)
    workers: list[WorkerProcess] = []
    try:
        alice = make_token(server, "user", name="alice")
        with (
            client(server.url, make_token(server, "user", name="bob")) as bob,
            client(server.url, make_token(server, "worker", name="shared")) as worker,
        ):
            worked, probed = ordinary_studies(bob, trials=100_000)
            token = make_token(server, "worker", name="worker")
            workers.append(
                WorkerProcess(
                    server,
                    tmp_path,
                    "shared",
                    *("--token", token, "--app-dir", str(app)),
                    *("--function", "scorer:score", "--task", ORDINARY_TASK),
                )
            )
            probes, record = measure(bob, worker, (worked, probed), server.url, alice)
            ordinary = bob.get(f"/api/v1/studies/{worked}").json()
        answers = dict(record.answers)
        assert not record.breaches, (record.breaches, answers)
        assert not probes.failures, probes.failures
        assert "attack error" not in " ".join(answers), answers
        # every attack was refused, each by its own budget
        assert not any(key.startswith("creation 2") for key in answers), answers
        assert answers.get("upload 413", 0) > 0, answers
        assert answers.get("lease 204", 0) > 0, answers
        assert all(
            status.startswith("4")
            for key in answers
            if key.startswith("harmful")
            for status in [key.split()[-1]]
        ), answers
        # the ordinary study kept its pace and its worker
        reads, leases = probes.ratio("reads"), probes.ratio("leases")
        assert reads <= 2.0 and leases <= 2.0, (reads, leases, answers)
        assert ordinary["n_complete"] >= 10, (ordinary, workers[0].log()[-2000:])
    finally:
        stop_workers(workers)
        server.stop()
