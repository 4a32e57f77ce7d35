"""Pruning through the SDK and the CLI against a real ``adserver``: ``trial.report``,
``TrialPruned`` in ``study.optimize``, pruned counts and listings."""

from __future__ import annotations

import csv
import io
import json

import pytest

from adclient import Client, Conflict, Invalid, LiveTrial, TrialPruned
from adclient.testing.servers import ServerProcess
from tests.client.cli_harness import ok, run

BOX = {"type": "box", "params": [{"name": "x", "low": -2.0, "high": 2.0}]}
MEDIAN = {"name": "median", "options": {"n_startup_trials": 2}}


def test_report_should_stop_and_optimize_tells_pruned(
    server: ServerProcess, client: Client
) -> None:
    study = client.create_study(
        name="sdk-pruning", space=BOX, proposer={"name": "random"}, pruner=MEDIAN
    )
    assert study.info.pruner.name == "median"
    for value in (1.0, 2.0):
        trial = study.ask()
        assert isinstance(trial, LiveTrial) and trial.should_stop is False
        assert trial.report(1, value) is False and trial.should_stop is False
        study.tell(trial, value)
    bad = study.ask()
    assert bad.report(0, -9.0) is False  # no complete trial has a value at step 0
    assert bad.report(1, 0.0) is True and bad.should_stop and bad.should_prune()
    assert bad.report(1, 0.0) is True  # a repeat: same answer, nothing stored twice
    assert [(r.step, r.value) for r in client.reports(bad)] == [(0, -9.0), (1, 0.0)]
    pruned = study.tell(bad, state="pruned")
    assert pruned.state == "pruned" and pruned.value == 0.0  # its last report
    with pytest.raises(Conflict):
        bad.report(2, 1.0)
    with pytest.raises(Invalid):
        client.report(bad, 2, float("nan"))  # refused before it travels

    sequence = iter([0.0, 5.0, 0.0, 5.0])

    def objective(trial: LiveTrial) -> float:
        value = next(sequence)
        if trial.report(1, value):
            raise TrialPruned()
        return value

    told = study.optimize(objective, n_trials=4)
    assert [t.state.value for t in told] == ["pruned", "complete", "pruned", "complete"]
    info = study.info
    assert (info.n_complete, info.n_pruned, info.best_value) == (4, 3, 5.0)
    assert {t.id for t in study.get_trials("pruned")} == {bad.id, told[0].id, told[2].id}
    rows = list(csv.DictReader(io.StringIO(study.export("csv"))))
    assert sum(row["state"] == "pruned" for row in rows) == 3


def test_cli_shows_and_tells_pruned(server: ServerProcess, client: Client) -> None:
    study = client.create_study(
        name="cli-pruning", space=BOX, proposer={"name": "random"}, pruner=MEDIAN, max_trials=3
    )
    first, second, third = study.ask(count=3)
    first.report(10, 0.5)
    told = ok(run(server.url, "tell", str(first.id), "--pruned"))
    assert "pruned: value 0.5" in told.stdout
    ok(run(server.url, "tell", str(second.id), "--pruned", "0.25"))
    status = ok(run(server.url, "status", str(study.id))).stdout
    assert any("pruned" in line and "2" in line for line in status.splitlines())
    assert any("pruner" in line and "median" in line for line in status.splitlines())
    listed = json.loads(
        ok(run(server.url, "trials", str(study.id), "--state", "pruned", "--json")).stdout
    )
    assert sorted(item["id"] for item in listed) == sorted([first.id, second.id])
    header = next(
        line for line in ok(run(server.url, "studies")).stdout.splitlines() if "id" in line
    )
    assert "pruned" in header
    ok(run(server.url, "tell", str(third.id), "1.0"))
    assert client.study_info(study.id).state.value == "complete"  # 1 complete + 2 pruned
