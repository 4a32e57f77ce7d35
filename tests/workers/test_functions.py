"""A function worker's runner on real jobs, no network: what the callable gets, and
what it may return."""

from __future__ import annotations

import math
import sys
from datetime import UTC, datetime
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest

from adclient.schemas import Curve, Job
from adworker.functions import FunctionJob, FunctionRunner
from adworker.runner import Cancelled
from tests.workers.robots import HALF_PI, make_job, stand_up_specs


def box_job(x: float) -> Job:
    return Job(
        trial_id=3,
        study_id=1,
        number=2,
        attempt=1,
        vector=[x],
        params={"x": x},
        task={"name": "f", "external": True, "seed": 4, "options": {"scale": 2}},
        space={"type": "box", "params": [{"name": "x", "low": -5, "high": 5}]},
        representation=None,
        lease_expires_at=datetime.now(UTC),
    )


@pytest.fixture
def runner_of(monkeypatch: pytest.MonkeyPatch):
    """A runner of ``function``, importable as ``scorers:function`` like a user's module."""

    def make(function: Any) -> FunctionRunner:
        module = ModuleType("scorers")
        module.function = function  # type: ignore[attr-defined]
        monkeypatch.setitem(sys.modules, "scorers", module)
        return FunctionRunner("scorers:function", "f")

    return make


def test_the_callable_gets_params_options_seed_and_a_design(runner_of, tmp_path: Path) -> None:
    seen: list[FunctionJob] = []

    def function(job: FunctionJob) -> float:
        seen.append(job)
        return 1.5

    outcome = runner_of(function)(box_job(0.5), tmp_path / "box", lambda: None)
    assert outcome.value == 1.5 and set(outcome.metrics) == {"time_total_s"}
    box = seen[0]
    assert (box.params, box.options, box.seed, box.number) == ({"x": 0.5}, {"scale": 2}, 4, 2)
    assert box.design is None and box.urdf_path is None

    job = make_job("stand-up", stand_up_specs(HALF_PI, HALF_PI))
    outcome = runner_of(function)(job, tmp_path / "design", lambda: None)
    design = seen[1]
    assert design.design is not None and [link.name for link in design.design.links] == list("abc")
    assert design.urdf_path is not None and "<robot" in design.urdf_path.read_text()
    assert [artifact.name for artifact in outcome.artifacts] == ["robot.urdf"]


@pytest.mark.parametrize(
    ("returned", "error"),
    [
        ({"score": 1.0}, "without 'value'"),
        (None, "value = None: not a number"),
        (math.nan, "not a finite number"),
        ({"value": 1.0, "steps": "many"}, "steps = 'many': not a number"),
        ({"value": 1.0, "energy": math.inf}, "energy = inf"),
    ],
)
def test_what_is_not_a_score_fails_the_job(
    runner_of, tmp_path: Path, returned: Any, error: str
) -> None:
    with pytest.raises((TypeError, ValueError), match=error):
        runner_of(lambda job: returned)(box_job(0.0), tmp_path, lambda: None)


def test_report_records_a_curve_and_stops_a_cancelled_job(runner_of, tmp_path: Path) -> None:
    def function(job: FunctionJob) -> float:
        for step in range(5):
            job.report(step * 10, step / 2)
        return 0.0

    outcome = runner_of(function)(box_job(0.0), tmp_path / "ok", lambda: None)
    curve = {artifact.name: artifact for artifact in outcome.artifacts}["curve.json"]
    read = Curve.model_validate_json(curve.data)
    assert [(point.steps, point.score) for point in read.train] == [
        (0, 0.0),
        (10, 0.5),
        (20, 1.0),
        (30, 1.5),
        (40, 2.0),
    ]
    assert read.evaluation == [] and read.score is not None and "reported" in read.score

    calls: list[int] = []

    def lost() -> None:
        calls.append(1)
        if len(calls) == 3:
            raise Cancelled("lease lost")

    with pytest.raises(Cancelled):
        runner_of(function)(box_job(0.0), tmp_path / "lost", lost)
    assert len(calls) == 3
