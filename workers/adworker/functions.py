"""Function workers: ``adworker --function module:callable --task NAME``.

A study's trials are scored by a plain Python callable instead of an installed task:
MuJoCo, Isaac, a real robot, anything. The callable gets one :class:`FunctionJob` and
returns the score (a float) or a mapping with ``value`` and any other numbers, which
become the trial's metrics. The worker loop around it is adworker's own: leases,
heartbeats, retries, ``--concurrency``, SIGTERM and artifacts. Nothing here imports
PyBullet or torch.
"""

from __future__ import annotations

import math
import re
import sys
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from adclient.design import DesignSpace
from adclient.designs import Design
from adclient.plugins import load_object
from adclient.schemas import (
    CURVE_ARTIFACT,
    NAME_PATTERN,
    Curve,
    Job,
    TaskConfig,
    TemplateSpace,
    TrainPoint,
)
from adworker.runner import Artifact, Outcome, Report, no_report

CONTENT_TYPES = {
    ".json": "application/json",
    ".png": "image/png",
    ".jpg": "image/jpeg",
    ".txt": "text/plain",
    ".csv": "text/csv",
    ".urdf": "application/xml",
    ".xml": "application/xml",
    ".mp4": "video/mp4",
}


@dataclass
class FunctionJob:
    """What the callable gets: the trial's params, its decoded design (design spaces),
    the study's task options and seed, a folder whose files become artifacts, and
    :meth:`report` for intermediate values."""

    trial_id: int
    study_id: int
    number: int
    attempt: int
    params: dict[str, Any]
    task: TaskConfig
    artifact_dir: Path
    """Every file written here is uploaded as an artifact of the trial (its name)."""
    design: Design | None = None
    urdf_path: Path | None = None
    """The robot's URDF, written by the worker: a design space's design, or a template
    expanded at the params (``design`` then None)."""
    reports: list[tuple[int, float]] = field(default_factory=list)
    _check: Callable[[], None] = field(default=lambda: None, repr=False)
    _report: Report = field(default=no_report, repr=False)

    @property
    def options(self) -> dict[str, Any]:
        return self.task.options

    @property
    def seed(self) -> int:
        return self.task.seed

    def report(self, step: int, value: float) -> None:
        """An intermediate value (a learning curve point), kept in order of the calls,
        sent to the server and uploaded as ``curve.json``. Raises
        :class:`~adworker.runner.Pruned` when the study's pruner stops the trial here
        (adworker then tells it pruned, with this value), and
        :class:`~adworker.runner.Cancelled` when the lease is lost or the worker is
        shutting down."""
        self.reports.append((int(step), float(value)))
        self._check()
        self._report(int(step), float(value))

    def check(self) -> None:
        """Raise :class:`~adworker.runner.Cancelled` when the job should stop."""
        self._check()


class FunctionRunner:
    """Runs jobs of one task name with a callable, named by an import string."""

    def __init__(self, reference: str, task: str, app_dir: Path | None = None) -> None:
        if not re.match(NAME_PATTERN, task):
            raise ValueError(f"--task {task!r} is not a task name")
        if app_dir is not None and str(app_dir) not in sys.path:
            sys.path.insert(0, str(app_dir))
        found = load_object(reference)
        if not callable(found):
            raise TypeError(f"--function {reference!r} is not callable")
        self.function: Callable[[FunctionJob], Any] = found
        self.task = task

    def tasks(self) -> list[str]:
        return [self.task]

    def learners(self) -> None:
        """Any: the function decides what a job's learner means."""
        return None

    def __call__(
        self, job: Job, workdir: Path, check: Callable[[], None], report: Report = no_report
    ) -> Outcome:
        started = time.perf_counter()
        artifact_dir = workdir / "artifacts"
        artifact_dir.mkdir(parents=True, exist_ok=True)
        call = FunctionJob(
            trial_id=job.trial_id,
            study_id=job.study_id,
            number=job.number,
            attempt=job.attempt,
            params=job.params,
            task=job.task,
            artifact_dir=artifact_dir,
            _check=check,
            _report=report,
        )
        if isinstance(job.space, DesignSpace | TemplateSpace):
            from adworker.job_robots import job_robot

            call.design, urdf = job_robot(job)
            call.urdf_path = artifact_dir / "robot.urdf"
            call.urdf_path.write_text(urdf)
        value, metrics = _score(self.function(call))
        metrics["time_total_s"] = time.perf_counter() - started
        if call.reports and not (artifact_dir / CURVE_ARTIFACT).exists():
            (artifact_dir / CURVE_ARTIFACT).write_bytes(_reported_curve(job, call.reports))
        artifacts = [
            Artifact(path.name, _content_type(path), path.read_bytes())
            for path in sorted(artifact_dir.iterdir())
            if path.is_file() and not path.name.startswith(".")
        ]
        return Outcome(value, metrics, artifacts, summary=f"value {value:.6g}")


def _reported_curve(job: Job, reports: list[tuple[int, float]]) -> bytes:
    """The job's ``curve.json`` (:class:`adclient.schemas.Curve`): its reported values,
    by step, as the training points."""
    curve = Curve(
        trial_id=job.trial_id,
        task=job.task.name,
        score="the values the function reported (job.report), by step",
        train=[TrainPoint(steps=step, score=value) for step, value in reports],
    )
    return curve.to_json()


def _score(result: Any) -> tuple[float, dict[str, float]]:
    """The value and metrics of what the callable returned: a number, or a mapping with
    ``value`` and other numbers."""
    if not isinstance(result, Mapping):
        return _number("value", result), {}
    if "value" not in result:
        raise ValueError(f"the function returned a mapping without 'value': {dict(result)}")
    metrics = {str(key): _number(str(key), item) for key, item in result.items()}
    return metrics.pop("value"), metrics


def _number(key: str, item: Any) -> float:
    try:
        number = float(item)
    except (TypeError, ValueError):
        raise TypeError(f"the function returned {key} = {item!r}: not a number") from None
    if not math.isfinite(number):
        raise ValueError(f"the function returned {key} = {number}: not a finite number")
    return number


def _content_type(path: Path) -> str:
    return CONTENT_TYPES.get(path.suffix.lower(), "application/octet-stream")
