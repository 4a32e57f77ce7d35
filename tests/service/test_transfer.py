"""Issue 27, the service's side of ``task.transfer``: which evaluated design a leased
job's controller starts from, and where a trial's controller started, as a real
``adserver`` keeps it. Workers of our own (SDK lease, artifact upload, tell) stand in
for adworker here, which tests/workers/test_transfer_worker_e2e.py runs for real."""

from __future__ import annotations

import csv
import io
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from adclient import Client
from adclient.decode import spec_vector, used_slots
from adclient.errors import Invalid
from adclient.pruning import CHECKPOINT_ARTIFACT
from adclient.schemas import Job
from tests.servers import ServerProcess

pytestmark = pytest.mark.e2e

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
AMONG = 2


def study_body(study: str, **task: Any) -> dict[str, Any]:
    """examples/multi-structure.yaml (six trees, eight free joint angles) as a study of
    workers of our own with transfer on."""
    body = yaml.safe_load((EXAMPLES / "multi-structure.yaml").read_text())
    body["proposer"] = {"name": "random", "seed": 7}
    body["task"] = {
        "name": "lift-highest",
        "external": True,
        "transfer": "nearest",
        "transfer_among": AMONG,
        **task,
    }
    return {**body, "name": study, "max_trials": 40}


def key(job: Job, vector: list[float]) -> tuple[int, np.ndarray]:
    assert job.representation is not None
    return spec_vector(job.representation, vector)


def value_of(vector: list[float]) -> float:
    return float(np.sin(3 * np.sum(vector)))


def test_a_job_starts_from_the_nearest_of_the_best_evaluated_designs_of_its_tree(
    live_server: ServerProcess,
) -> None:
    """Every leased job is checked against what the service has seen: a job of a tree
    with evaluated designs that left a checkpoint starts from the nearest of the
    ``transfer_among`` best of them; one of a tree without any starts from nothing; a
    design of another tree, or one that left no checkpoint, is never a source."""
    with Client(live_server.url) as client:
        study = client.create_study(study_body("transfer-choice"))
        done: list[tuple[int, list[float], float]] = []  # id, vector, value (checkpointed)
        started_from = 0
        for index in range(40):
            job = client.lease("w")
            assert job is not None and job.study_id == study.id
            tree, specs = key(job, job.vector)
            same = [(i, v, y) for i, v, y in done if key(job, v)[0] == tree]
            if not same:
                assert job.transfer is None, (index, job.transfer)
            else:
                assert job.transfer is not None and job.transfer.artifact == CHECKPOINT_ARTIFACT
                best = sorted(same, key=lambda row: (-row[2], row[0]))[:AMONG]
                assert job.representation is not None
                used = used_slots(
                    job.representation.spec_names, job.representation.structures[tree]
                )
                distances = {
                    i: float(np.sqrt(np.mean((key(job, v)[1][used] - specs[used]) ** 2)))
                    for i, v, _ in best
                }
                assert job.transfer.trial_id == min(distances, key=lambda i: (distances[i], i))
                assert job.transfer.distance == pytest.approx(distances[job.transfer.trial_id])
                started_from += 1
            value = value_of(job.vector)
            if index % 3 != 2:  # every third design leaves no checkpoint: never a source
                client.put_artifact(job.trial_id, CHECKPOINT_ARTIFACT, b"PK", worker_id="w")
                done.append((job.trial_id, job.vector, value))
            source = job.transfer.trial_id if job.transfer is not None else None
            told = client.tell(job.trial_id, value, worker_id="w", transfer_from=source)
            assert told.info.get("transfer_from") == source
        assert started_from >= 20  # six trees, 40 designs: most start from another


def test_transfer_from_names_another_trial_of_the_same_study_or_nothing_is_stored(
    live_server: ServerProcess,
) -> None:
    """A tell (or pause) naming a trial of another study, or the trial itself, is
    refused and leaves the trial running; a right one is kept in its info and exports."""
    with Client(live_server.url) as client:
        study = client.create_study(study_body("transfer-a", name="alpha"))
        client.create_study(study_body("transfer-b", name="beta"))
        foreign, source, mine = (
            client.lease("w", tasks=["beta"]),
            client.lease("w", tasks=["alpha"]),
            client.lease("w", tasks=["alpha"]),
        )
        assert foreign is not None and source is not None and mine is not None
        for wrong in (foreign.trial_id, mine.trial_id):
            with pytest.raises(Invalid, match="transfer_from"):
                client.tell(mine.trial_id, 1.0, worker_id="w", transfer_from=wrong)
            assert client.get_trial(mine.trial_id).state == "running"
        client.tell(source.trial_id, 0.5, worker_id="w")
        told = client.tell(mine.trial_id, 0.7, worker_id="w", transfer_from=source.trial_id)
        assert told.info["transfer_from"] == source.trial_id
        rows = csv.DictReader(io.StringIO(client.export(study.id, "csv")))
        cells = {row["id"]: row["transfer_from"] for row in rows}
        assert cells == {str(source.trial_id): "", str(mine.trial_id): str(source.trial_id)}


def test_a_learner_that_cannot_start_from_another_controller_is_refused(
    live_server: ServerProcess,
) -> None:
    with Client(live_server.url) as client:
        body = study_body("transfer-fast")
        body["task"] = {"name": "lift-highest", "learner": "fast", "transfer": "nearest"}
        with pytest.raises(Invalid, match="learner 'fast' cannot start from another"):
            client.create_study(body)
        assert all(s.name != "transfer-fast" for s in client.studies())
