"""A job as it travels from server to worker (``adclient.schemas.Job``): its task, space
and pruner leave out the fields at their defaults, so a worker older than a field reads
every job that does not use it (docs/worker.md, "Workers older than the server")."""

from __future__ import annotations

import json
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import pytest
import yaml
from pydantic import ValidationError

from adclient.schemas import Job, StudyCreate

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def job_of(**parts: Any) -> Job:
    """A job of trial 1 with this task, space and pruner."""
    return Job.model_validate(
        {
            "trial_id": 1,
            "study_id": 1,
            "number": 0,
            "attempt": 1,
            "vector": [0.5],
            "params": {},
            "representation": None,
            "lease_expires_at": datetime.now(UTC),
            **parts,
        }
    )


@pytest.mark.parametrize("example", sorted(path.stem for path in EXAMPLES.glob("*.yaml")))
def test_a_job_travels_without_defaults_and_reads_back_the_same(example: str) -> None:
    study = StudyCreate.model_validate(yaml.safe_load((EXAMPLES / f"{example}.yaml").read_text()))
    assert study.task is not None
    job = job_of(
        task=study.task.model_dump(mode="json"),
        space=study.space.model_dump(mode="json"),
        pruner=study.pruner.model_dump(mode="json"),
    )
    wire = job.model_dump(mode="json")
    assert Job.model_validate(wire) == job  # a worker reads the very job
    assert wire["space"]["type"] == study.space.type  # the union's discriminator stays
    full = job.task.model_dump(mode="json")
    assert set(wire["task"]) < set(full)  # defaults left out
    assert "shared_carries" not in wire["task"]  # no example sets the newest task field
    for part in ("space", "pruner"):
        whole = getattr(job, part).model_dump(mode="json")
        assert len(json.dumps(wire[part])) <= len(json.dumps(whole)), part


def test_a_pruners_options_travel_without_their_defaults() -> None:
    """The pruner's options are a dict its options model fills in: they leave out the
    defaults too, so an option added later does not make older workers refuse every
    ASHA job."""
    from adclient.pruning import PrunerConfig

    pruner = PrunerConfig.model_validate(
        {"name": "asha", "options": {"min_resource": 2000}, "report_every": 500}
    )
    assert set(pruner.options) > {"min_resource", "reduction_factor", "promotion"}
    job = job_of(
        task={"name": "stand-up"},
        space={"type": "box", "params": [{"name": "x", "low": 0.0, "high": 1.0}]},
        pruner=pruner,
    )
    wire = job.model_dump(mode="json")
    assert wire["pruner"] == {
        "name": "asha",
        "options": {"min_resource": 2000},
        "report_every": 500,
    }
    assert wire["task"] == {"name": "stand-up"}
    assert Job.model_validate(wire) == job


@pytest.mark.parametrize("field", ["resume", "transfer", "shared"])
@pytest.mark.parametrize("name", ["../escape.zip", "a/b.zip", ".hidden", ""])
def test_a_job_naming_an_artifact_outside_the_name_whitelist_is_not_read(
    field: str, name: str
) -> None:
    """A worker writes what a job starts from into its job folder; an artifact name is
    read only if it is one the server could have stored (``NAME_PATTERN``), so no job
    makes it write or fetch outside that folder's one file (``Client.lease`` turns the
    error into ``UnreadableJob``)."""
    sources = {
        "resume": {"artifact": name, "step": 1, "rung": 0},
        "transfer": {"trial_id": 2, "artifact": name, "distance": 0.1},
        "shared": {"version": 1, "trial_id": 2, "artifact": name},
    }
    box = {"type": "box", "params": [{"name": "x", "low": 0.0, "high": 1.0}]}
    base = {"task": {"name": "stand-up"}, "space": box}
    good = {**sources[field], "artifact": "checkpoint.zip"}
    assert getattr(job_of(**base, **{field: good}), field).artifact == "checkpoint.zip"
    with pytest.raises(ValidationError, match=f"{field}.artifact"):
        job_of(**base, **{field: sources[field]})


def test_the_pruning_modules_artifact_names_are_the_schemas_names() -> None:
    from adclient.pruning import ARTIFACT_NAME
    from adclient.schemas.common import NAME_PATTERN

    assert ARTIFACT_NAME == NAME_PATTERN
