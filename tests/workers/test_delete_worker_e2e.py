"""Deleting a study while real ``adworker`` processes hold leases on its trials, on
SQLite and PostgreSQL: refused until forced, then the study's rows and files are gone,
the workers are told their trials are gone (404s, no server error) and go on working."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import httpx
import pytest

from adclient import Client
from adclient.testing.servers import SDK_HEADERS, ServerProcess
from adclient.testing.workers import PATIENCE, WorkerProcess, stop_workers, wait_for

pytestmark = pytest.mark.e2e

HOLDER = '''
import time


def hold(job):
    """The first trial ends at once; the others report until their lease is taken away."""
    (job.artifact_dir / "note.txt").write_text(f"trial {job.number}")
    step = 0
    while job.number > 0 and job.options.get("hold"):
        job.report(step, 0.0)
        step += 1
        time.sleep(0.1)
    return job.params["x"]
'''


def study_body(name: str, *, hold: bool, max_trials: int) -> dict[str, object]:
    return {
        "name": name,
        "space": {"type": "box", "params": [{"name": "x", "low": 0, "high": 1}]},
        "proposer": {"name": "random"},
        "task": {"name": "hold", "external": True, "options": {"hold": hold}},
        "max_trials": max_trials,
    }


def test_delete_during_leases_cancels_them_and_removes_the_files(
    server_factory: Callable[..., ServerProcess], tmp_path: Path
) -> None:
    server = server_factory()
    app = tmp_path / "app"
    app.mkdir()
    (app / "holder.py").write_text(HOLDER)
    function = ["--app-dir", str(app), "--function", "holder:hold", "--task", "hold"]
    with Client(server.url) as client:
        doomed = client.create_study(study_body("doomed, 設計", hold=True, max_trials=3))
        workers = [WorkerProcess(server, tmp_path, f"w{i}", *function) for i in (1, 2)]
        try:
            wait_for(
                lambda: (
                    (info := client.study_info(doomed.id)).n_complete == 1 and info.n_running == 2
                ),
                "one trial told and two held",
            )
            files = server.artifact_dir / str(doomed.id)
            assert [path.name.split(".")[0] for path in files.rglob("note.txt.*")] == ["note"]
            held = {t.id: t.worker_id for t in client.trials(doomed.id, "running")}
            assert sorted(held.values()) == ["w1", "w2"]

            with httpx.Client(base_url=server.url, headers=SDK_HEADERS, timeout=30) as api:
                refused = api.delete(f"/api/v1/studies/{doomed.id}")
                assert refused.status_code == 409
                assert "'w1', 'w2'" in refused.json()["detail"]
                assert client.study_info(doomed.id).n_running == 2
                forced = api.delete(f"/api/v1/studies/{doomed.id}", params={"force": "true"})
                assert forced.status_code == 204
                assert api.get(f"/api/v1/studies/{doomed.id}").status_code == 404
                for trial_id in held:
                    assert api.get(f"/api/v1/trials/{trial_id}").status_code == 404
            assert not files.exists()

            # Both workers hear their trials are gone and take the next study's work.
            for worker in workers:
                wait_for(lambda w=worker: "not found" in w.log(), f"{worker.worker_id} told")
            kept = client.create_study(study_body("kept", hold=False, max_trials=4))
            done = kept.wait(poll=0.2, timeout=PATIENCE)
            assert done.n_complete == 4
            for worker in workers:
                assert worker.process.poll() is None, worker.log()
                assert "Traceback" not in worker.log()
            assert not files.exists()
        finally:
            stop_workers(workers)
    log = server.log_path.read_text(errors="replace")
    assert "Traceback" not in log and " 500" not in log, log[-3000:]
