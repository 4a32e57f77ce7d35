"""Issue 39, one fixed design end to end: examples/one-design.yaml submitted with
``adclient submit --wait`` to a real adserver, evaluated by a real adworker (PyBullet,
a tiny training budget), each repeat on its own seed, and the spread printed."""

from __future__ import annotations

import json
import statistics
from pathlib import Path

import pytest
import yaml

from adclient import Client
from adclient.testing.workers import run_adclient
from adworker.evaluate import EVAL_SEED_STRIDE
from tests.workers.robots import EXAMPLES

pytestmark = pytest.mark.e2e

REPEATS = 3


def spread_line(text: str, name: str = "value") -> str:
    """The line of CLI output that gives an objective's spread."""
    return next(line for line in text.splitlines() if f"spread of {name}" in line)


def test_one_design_repeats_on_their_own_seeds_and_the_cli_prints_the_spread(
    server, workers, tmp_path: Path
) -> None:
    body = yaml.safe_load((EXAMPLES / "one-design.yaml").read_text())
    body["max_trials"] = REPEATS
    body["task"].update(train_steps=256, eval_episodes=2, seed=40)
    study_file = tmp_path / "one-design.yaml"
    study_file.write_text(yaml.safe_dump(body))
    worker = workers(server, "repeater", "--max-jobs", str(REPEATS))
    submitted = run_adclient(server, "submit", "--wait", "--poll", "0.2", str(study_file))
    assert submitted.returncode == 0, (submitted.stdout, submitted.stderr, worker.log())
    assert worker.wait() == 0, worker.log()
    with Client(server.url) as client:
        (info,) = client.studies()
        trials = client.trials(info.id)
        assert info.fixed and [t.state for t in trials] == ["complete"] * REPEATS
        assert all(t.params == trials[0].params and t.vector == [] for t in trials)
        assert trials[0].params["b.length"] == 0.4
        seeds = [t.info["seed"] for t in trials]
        assert seeds == [40, 41, 42]
        for trial, seed in zip(trials, seeds, strict=True):  # the worker trained on it
            curve = json.loads(client.get_artifact(trial, "curve.json"))
            evaluated = [episode["seed"] for episode in curve["evaluation"]]
            assert evaluated == [(seed + 1) * EVAL_SEED_STRIDE + i for i in range(2)]
        values = [t.value for t in trials]
        assert len(set(values)) > 1, values  # other seeds, other scores
    expected = (
        f"{REPEATS} repeats: mean {statistics.fmean(values):.6g}, "
        f"std {statistics.stdev(values):.6g}, min {min(values):.6g}, "
        f"median {statistics.median(values):.6g}, max {max(values):.6g}"
    )
    assert f"{REPEATS} complete, 0 failed" in submitted.stdout
    assert "one design: nothing searched" in submitted.stdout
    assert spread_line(submitted.stdout).endswith(expected), submitted.stdout
    assert "best trial" not in submitted.stdout
    status = run_adclient(server, "status", str(info.id))
    assert status.returncode == 0, status.stderr
    assert expected in spread_line(status.stdout), status.stdout
    assert "each trial a repeat on its own seed" in status.stdout
    assert "none (one design)" in status.stdout  # no proposer runs
