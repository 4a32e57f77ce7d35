"""A worker builds a template study's robot from the URDF its server expanded once
(``Job.urdf``), and expands the template itself only for a job without one (a trial
stored before the server kept URDFs, or an older server)."""

from __future__ import annotations

from datetime import UTC, datetime

import pytest

from adclient.schemas import Job
from adworker.job_robots import job_robot
from adworker.runner import JobError
from tests.picky_template import JOINTED, PICKY_SPACE, base_size, picky_size


def picky_job(n: int, urdf: str | None) -> Job:
    return Job.model_validate(
        {
            "trial_id": 1,
            "study_id": 1,
            "number": 0,
            "attempt": 1,
            "vector": [float(n)],
            "params": {"n": n},
            "task": {"name": "lift-highest"},
            "space": PICKY_SPACE,
            "representation": None,
            "lease_expires_at": datetime.now(UTC),
            "urdf": urdf,
        }
    )


def test_the_server_s_urdf_is_used_and_the_template_not_expanded_again() -> None:
    given = (
        '<robot name="given"><link name="base"><visual><geometry><box size="0.1 0.1 0.1"/>'
        f"</geometry></visual></link>{JOINTED}</robot>"
    )
    # at n = 1 the template does not expand: were it expanded here, this would fail
    assert job_robot(picky_job(1, given)) == (None, given)


def test_a_job_without_a_urdf_has_its_template_expanded_by_the_worker() -> None:
    design, urdf = job_robot(picky_job(2, None))
    assert design is None and base_size(urdf) == pytest.approx(picky_size(2))
    with pytest.raises(JobError, match="division by zero"):
        job_robot(picky_job(1, None))
