"""Issue 36's finding, end to end: a managed study whose every proposal raises, beside a
good one, one real adworker. Before, each lease tried the failing study first and
answered 500, and the good study completed 0 of 3 trials in 200 s; now the good one
completes, no lease fails, and the failing study says why on its answer, on
``adclient status`` and ``adclient studies``, and in /metrics."""

from __future__ import annotations

from pathlib import Path

import httpx
import pytest
from typer.testing import CliRunner

from adclient import Client
from adclient.cli import app
from adclient.testing.servers import ServerProcess
from adclient.testing.workers import PATIENCE, WorkerProcess
from tests.failing_proposals import ERROR, design_study, unfit_representation

pytestmark = pytest.mark.e2e

TASK = {"name": "score", "external": True}
SCORER = """
def score(job):
    return job.params["x"]
"""


def cli(server: ServerProcess, *args: str) -> str:
    result = CliRunner().invoke(app, ["--server", server.url, *args], env={"COLUMNS": "400"})
    assert result.exit_code == 0, (result.stdout, result.exception)
    return result.stdout


def test_a_failing_study_leaves_a_good_one_to_complete(
    server: ServerProcess, tmp_path: Path
) -> None:
    (tmp_path / "scorer.py").write_text(SCORER)
    with Client(server.url) as client:
        failing = client.create_study(design_study("failing", task=TASK, max_trials=3))
        unfit_representation(server.database_url, failing.id)
        good = client.create_study(
            name="good",
            space={"type": "box", "params": [{"name": "x", "low": 0, "high": 1}]},
            proposer={"name": "random", "seed": 1},
            task=TASK,
            max_trials=3,
        )
        worker = WorkerProcess(
            server,
            tmp_path,
            "w",
            *("--app-dir", str(tmp_path), "--function", "scorer:score", "--task", "score"),
        )
        try:
            done = good.wait(poll=0.2, timeout=PATIENCE)
        finally:
            worker.stop()
        assert (done.n_complete, done.n_failed) == (3, 0), worker.log()
        assert "lease failed" not in worker.log(), worker.log()

        info = client.study_info(failing.id)
        assert info.n_trials == 0 and info.state.value == "running"
        assert info.proposal_failures >= 1
        assert info.proposal_error is not None and info.proposal_error.startswith(ERROR)
        assert info.proposal_retry_at is not None

    metrics = httpx.get(f"{server.url}/metrics").text
    assert f'activedesign_proposal_failures{{study="{failing.id}"}} ' in metrics
    lease_answers = [
        line
        for line in metrics.splitlines()
        if line.startswith("activedesign_http_request_duration_seconds_count")
        and 'route="/api/v1/jobs/lease"' in line
    ]
    assert lease_answers and all('status="500"' not in line for line in lease_answers)

    status = cli(server, "status", str(failing.id))
    assert f"failing ({info.proposal_failures} in a row); workers skip the study until" in status
    assert ERROR in status
    (row,) = [line for line in cli(server, "studies").splitlines() if " failing " in line]
    assert "running (proposals failing)" in row
