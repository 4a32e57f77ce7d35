"""Issue 39: a study that no worker can serve does not wait in silence. The server keeps
the tasks and learners each worker leases for (GET /api/v1/workers); ``adclient
workers`` lists them, ``adclient status`` of a running managed study says how many
recent workers serve its task and learner or what to start (the server's word, GET
/studies/{id}/serving), and ``submit --wait`` says so when nothing starts. A real
server; workers are raw leases, as a worker of any language makes them."""

from __future__ import annotations

import sqlite3
import threading
from collections.abc import Iterator
from datetime import datetime, timedelta
from pathlib import Path

import httpx
import pytest

from adclient import Client
from adclient.testing.servers import SDK_HEADERS, ServerProcess
from tests.client.cli_harness import ok, run, write_study

BOX = {"type": "box", "params": [{"name": "x", "low": 0.0, "high": 1.0}]}


@pytest.fixture
def server(tmp_path: Path) -> Iterator[ServerProcess]:
    """A server of its own: a worker that serves any task would serve every study."""
    process = ServerProcess(database_url=f"sqlite:///{tmp_path / 's.db'}", workdir=tmp_path)
    yield process.start()
    process.stop()


def managed(task: str, name: str) -> dict[str, object]:
    return {
        "name": name,
        "space": BOX,
        "proposer": {"name": "random"},
        "task": {"name": task, "external": True},
        "max_trials": 2,
    }


def words(text: str) -> str:
    return " ".join(text.replace("│", " ").split())


def test_workers_and_status_say_who_serves_a_study(server: ServerProcess) -> None:
    with Client(server.url) as client:
        study = client.create_study(managed("reach-point", "reach")).id
        said = words(ok(run(server.url, "status", str(study))).stdout)
        unserved = "none serving task 'reach-point' with learner 'fast' seen in the last 90 s"
        assert f"workers {unserved}" in said, said
        assert (
            f"adworker --server {server.url} --function MODULE:FUNCTION --task reach-point" in said
        )

        assert client.lease("sim-1", tasks=["other-sim"]) is None
        said = words(ok(run(server.url, "status", str(study))).stdout)
        assert unserved in said
        assert "(1 other workers serve other tasks or learners)" in said

        job = client.lease("sim-2", tasks=["reach-point", "other-sim"])
        assert job is not None and job.study_id == study
        said = words(ok(run(server.url, "status", str(study))).stdout)
        assert (
            "workers 1 serving task 'reach-point' with learner 'fast', seen in the last 90 s"
            in said
        )

        listed = {w.worker_id: w.tasks for w in client.workers()}
        assert listed == {"sim-1": ["other-sim"], "sim-2": ["other-sim", "reach-point"]}
        client.lease("anything")  # a worker naming no task (it takes the study's 2nd trial)
        assert {w.worker_id: w.tasks for w in client.workers()}["anything"] is None
    table = words(ok(run(server.url, "workers")).stdout)
    assert "workers: 3" in table
    assert "sim-2" in table and "other-sim, reach-point" in table
    assert "anything" in table and " any " in table
    # An unmanaged study has no workers row.
    with Client(server.url) as client:
        plain = client.create_study({"name": "plain", "space": BOX}).id
    assert "workers" not in words(ok(run(server.url, "status", str(plain))).stdout).split()


def test_submit_wait_says_when_no_worker_serves_the_study(
    server: ServerProcess, tmp_path: Path
) -> None:
    """After 10 s with nothing started; then the study is stopped and the wait ends."""

    def stop_later() -> None:
        with Client(server.url) as client:
            while not (found := [s for s in client.studies() if s.name == "unserved"]):
                threading.Event().wait(0.05)
            threading.Event().wait(12)
            client.stop_study(found[0].id)

    stopper = threading.Thread(target=stop_later, daemon=True)
    stopper.start()
    path = write_study(tmp_path, managed("reach-point", "unserved"))
    result = ok(run(server.url, "submit", "--wait", "--poll", "0.2", str(path)))
    stopper.join()
    said = words(result.stderr)
    assert "no worker: none serving task 'reach-point' with learner 'fast' seen" in said, said
    assert said.count("no worker:") == 1


def test_a_worker_without_the_study_s_learner_does_not_serve_it(server: ServerProcess) -> None:
    """A worker names the learners that load on it: one without the study's learner
    leases none of its trials, and status names the learner it waits for; one with it
    does, and the workers table shows each one's learners (any: it named none)."""
    with Client(server.url) as client:
        study = client.create_study(managed("reach-point", "learned")).id
        for learners in (["../fast"], ["fast"] * 257, "fast"):
            refused = httpx.post(
                f"{server.url}/api/v1/jobs/lease",
                json={"worker_id": "hostile", "learners": learners},
                headers=SDK_HEADERS,
            )
            assert refused.status_code == 422 and "learners" in refused.text, refused.text
        assert client.workers() == []  # refused: nothing stored
        assert client.lease("no-fast", tasks=["reach-point"], learners=["ppo"]) is None
        said = words(ok(run(server.url, "status", str(study))).stdout)
        assert "workers none serving task 'reach-point' with learner 'fast' seen" in said, said
        assert "(1 other workers serve other tasks or learners)" in said
        job = client.lease("has-fast", tasks=["reach-point"], learners=["fast", "ppo"])
        assert job is not None and job.study_id == study
        said = words(ok(run(server.url, "status", str(study))).stdout)
        assert "workers 1 serving task 'reach-point' with learner 'fast', seen" in said
        learners = {w.worker_id: w.learners for w in client.workers()}
        assert learners == {"no-fast": ["ppo"], "has-fast": ["fast", "ppo"]}
    table = words(ok(run(server.url, "workers")).stdout)
    assert "learners" in table and "reach-point fast, ppo" in table, table


def test_workers_table_shows_each_worker_s_state(server: ServerProcess, tmp_path: Path) -> None:
    """The state column: working (holds a trial), idle (holds none, heard from lately),
    gone (its last contact set back past the server's 90 s in the SQLite file)."""
    with Client(server.url) as client:
        client.create_study(managed("state-sim", "states"))
        assert client.lease("busy", tasks=["state-sim"]) is not None
        assert client.lease("left", tasks=["state-sim"]) is not None
        assert client.lease("resting", tasks=["other-sim"]) is None
    with sqlite3.connect(tmp_path / "s.db") as db:
        (seen,) = db.execute("SELECT last_seen_at FROM workers WHERE worker_id = 'left'").fetchone()
        back = datetime.fromisoformat(seen) - timedelta(seconds=91)
        db.execute(
            "UPDATE workers SET last_seen_at = ? WHERE worker_id = 'left'",
            (back.isoformat(sep=" "),),
        )
    with Client(server.url) as client:
        states = {w.worker_id: w.state for w in client.workers()}
    assert states == {"busy": "working", "left": "gone", "resting": "idle"}
    lines = ok(run(server.url, "workers")).stdout.splitlines()
    rows = {cells[0]: cells[1] for line in lines if len(cells := words(line).split()) > 2}
    assert rows["busy"] == "working" and rows["left"] == "gone" and rows["resting"] == "idle"
    assert "state" in words(" ".join(lines)).split()  # the header
