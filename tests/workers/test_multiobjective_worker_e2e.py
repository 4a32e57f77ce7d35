"""examples/score-vs-mass.yaml end to end (issue 17): a real adserver and a real adworker,
the study submitted with ``adclient submit --wait`` as a person would, then checked over
HTTP and with ``adclient pareto``. The server is the workers' ``server`` fixture (SQLite).

The study file is the example's, with a small budget (``adclient submit`` takes no
budget override): 6 trials instead of 40, 256 training steps of the ``fast`` learner it
already uses. Its links are aluminium (density 2700 kg/m^3), so every trial's ``mass``
metric is density x volume of the decoded design, and its second objective.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import httpx
import pytest
import yaml

from adclient import Client
from adclient.decode import decode, identity_representation
from adclient.design import DesignSpace
from adclient.schemas import Trial
from adclient.testing.servers import ServerProcess
from adclient.testing.workers import WorkerProcess, run_adclient
from adclient.urdf import design_mass

pytestmark = [pytest.mark.slow, pytest.mark.e2e]

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "score-vs-mass.yaml"
TRIALS = 6
TRAIN_STEPS = 256


def small_copy(tmp_path: Path) -> tuple[Path, dict]:
    body = yaml.safe_load(EXAMPLE.read_text(encoding="utf-8"))
    assert body["objectives"] == [
        {"metric": "score", "direction": "maximize"},
        {"metric": "mass", "direction": "minimize"},
    ]
    assert body["space"]["parts"]["link"]["density"] == 2700.0
    assert body["task"]["learner"] == "fast"
    body["max_trials"] = TRIALS
    body["task"]["train_steps"] = TRAIN_STEPS
    path = tmp_path / "score-vs-mass-small.yaml"
    path.write_text(yaml.safe_dump(body), encoding="utf-8")
    return path, body


def dominates(a: list[float], b: list[float]) -> bool:
    """a dominates b: score (maximised) and mass (minimised) no worse, one better."""
    return a[0] >= b[0] and a[1] <= b[1] and (a[0] > b[0] or a[1] < b[1])


def test_score_vs_mass_example_runs_with_submit_wait_and_has_a_pareto_front(
    server: ServerProcess, tmp_path: Path
) -> None:
    path, body = small_copy(tmp_path)
    worker = WorkerProcess(server, tmp_path, "mo")
    try:
        submitted = run_adclient(server, "submit", str(path), "--wait", "--poll", "0.2")
        assert submitted.returncode == 0, submitted.stdout + submitted.stderr + worker.log()
    finally:
        worker.stop()
    first = submitted.stdout.splitlines()[0]
    assert first.startswith("study ") and " created: score-vs-mass" in first, submitted.stdout
    study_id = int(first.split()[1])
    assert f"study {study_id} complete: {TRIALS} complete, 0 failed" in submitted.stdout

    space = DesignSpace.model_validate(body["space"])
    representation = identity_representation(space)
    with Client(server.url) as client:
        info = client.study_info(study_id)
        assert info.state.value == "complete" and info.n_complete == TRIALS
        assert info.objective_names == ["score", "mass"]
        assert [direction.value for direction in info.directions] == ["maximize", "minimize"]
        trials = client.trials(study_id)
        assert len(trials) == TRIALS
        for trial in trials:
            assert trial.state.value == "complete", trial.message
            # values: [the value the worker told (the task's score), its mass metric];
            # a trial of several objectives carries values, and value is null
            assert trial.values == [trial.metrics["score_mean"], trial.metrics["mass"]]
            assert trial.value is None and trial.feasible is not False
            # the mass is the aluminium links' density x volume, as decoded
            design = decode(space, representation, trial.vector)
            assert trial.metrics["mass"] == pytest.approx(design_mass(design), rel=1e-12)
            expected = sum(
                2700.0 * math.pi * trial.params[f"{n}.radius"] ** 2 * trial.params[f"{n}.length"]
                for n in "abc"
            )
            assert trial.metrics["mass"] == pytest.approx(expected, rel=1e-12)
            for name in "abc":  # the derived mass is shown with the density
                assert trial.params[f"{name}.density"] == 2700.0
                assert f"{name}.mass" in trial.params
        front = client.pareto(study_id)

    assert front, "the Pareto front is empty"
    complete = [trial.values for trial in trials if trial.values is not None]
    on_front = {trial.id for trial in front}
    for trial in front:
        assert trial.values is not None
        assert not any(dominates(other, trial.values) for other in complete), trial.values
    brute = {  # every complete trial no other dominates is on the front
        trial.id
        for trial in trials
        if trial.values is not None
        and not any(dominates(other, trial.values) for other in complete)
    }
    assert on_front == brute

    # a front design's params, enqueued in a study of the same space, are that design
    # (the derived masses shown with them included); a mass of one's own is refused
    unmanaged = {key: value for key, value in body.items() if key != "task"}
    with httpx.Client(base_url=server.url, timeout=30) as http:
        again_id = http.post("/api/v1/studies", json=unmanaged).json()["id"]
        url = f"/api/v1/studies/{again_id}/trials"
        enqueued = http.post(url, json={"params": front[0].params})
        assert enqueued.status_code == 201, enqueued.text
        assert enqueued.json()["params"] == front[0].params
        heavier = dict(front[0].params, **{"b.mass": front[0].params["b.mass"] * 2})
        refused = http.post(url, json={"params": heavier})
        assert refused.status_code == 422 and "'b.mass'" in refused.json()["detail"]
        assert "is not this link's mass" in refused.json()["detail"]

    shown = run_adclient(server, "pareto", str(study_id))
    assert shown.returncode == 0, shown.stderr
    assert f"{len(front)} trials on the Pareto front of score (max), mass (min)" in shown.stdout
    as_json = run_adclient(server, "pareto", str(study_id), "--json")
    assert as_json.returncode == 0, as_json.stderr
    printed = [Trial.model_validate(item) for item in json.loads(as_json.stdout)]
    assert [trial.id for trial in printed] == [trial.id for trial in front]
    assert [trial.values for trial in printed] == [trial.values for trial in front]
