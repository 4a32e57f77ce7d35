"""What the worker loop runs a job with, in terms light enough for any worker.

The loop (:mod:`adworker.worker`) leases, heartbeats, reports and uploads; a *runner*
turns one job into an :class:`Outcome`. Two runners exist: installed tasks
(:class:`adworker.evaluate.TaskRunner`: simulate, train, score) and a plain Python
callable (:class:`adworker.functions.FunctionRunner`, ``adworker --function``). This
module imports neither PyBullet nor torch, so a function worker never does.
"""

from __future__ import annotations

import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

from adclient.plugins import LearnerSpec, TaskSpec
from adclient.schemas import Job

MESSAGE_LIMIT = 4000
"""The most characters of a failed trial's message."""
TRANSFER_FILE = "transfer-source.zip"
"""Where the worker puts the checkpoint a job's controller starts from (``job.transfer``)."""
SHARED_FILE = "shared-source.npz"
"""Where the worker puts the shared controller's version a job starts from (``job.shared``)."""


class Cancelled(Exception):
    """The worker asked the evaluation to stop (lease lost, or shutting down)."""


class Pruned(Exception):
    """The study's pruner stopped the trial at ``step`` (its report of ``value``).

    ``pause``: the pruner would rather pause it (ASHA with promotion); a learner that can
    resume attaches its state as ``checkpoint`` (bytes) while the exception unwinds,
    and the worker then pauses the trial with it instead of telling it pruned."""

    def __init__(self, step: int, value: float, *, pause: bool = False) -> None:
        super().__init__(f"{'paused' if pause else 'pruned'} at step {step} (value {value:.6g})")
        self.step = step
        self.value = value
        self.pause = pause
        self.checkpoint: bytes | None = None
        self.transfer_from: int | None = None
        """The trial whose controller the stopped one started from, if it did."""
        self.metrics: dict[str, float] = {}
        """Metrics the learner's caller adds to the pause (a warm start's)."""
        self.budget: int | None = None
        """The steps the stopped trial was training to: a promoted one trains on to them."""


Report = Callable[[int, float], None]
"""Reports an intermediate value (step, value); raises :class:`Pruned` when the study's
pruner stops the trial there, :class:`Cancelled` when the lease is lost."""


def no_report(step: int, value: float) -> None:
    return None


class JobError(ValueError):
    """The job cannot be evaluated as given (no design space, unknown task...)."""


@dataclass
class Artifact:
    name: str
    content_type: str
    data: bytes


@dataclass
class Outcome:
    """What the loop reports for a job: the score, metrics, artifacts, and a log line."""

    value: float
    metrics: dict[str, float]
    artifacts: list[Artifact] = field(default_factory=list)
    summary: str = ""
    transfer_from: int | None = None
    """The trial of the same study whose controller this job started from, if any."""
    shared_start: bytes | None = None
    """A ``task.transfer: shared`` job: the weights it started from (its update, the
    ``SHARED_ARTIFACT`` among ``artifacts``, is merged against them)."""


class Runner(Protocol):
    def tasks(self) -> list[str]:
        """The task names to lease: the ones this runner can run."""
        ...

    def learners(self) -> list[str] | None:
        """The learner names to lease (the ones that load here); None: any learner."""
        ...

    def __call__(
        self, job: Job, workdir: Path, check: Callable[[], None], report: Report = no_report
    ) -> Outcome:
        """Run one job in its own folder; ``check`` raises :class:`Cancelled` to stop;
        ``report`` sends intermediate values (and raises :class:`Pruned` to stop)."""
        ...


def factory_problem(spec: TaskSpec | LearnerSpec) -> str | None:
    """Why the spec's factory does not load here (a missing simulator...), or None."""
    try:
        spec.load_factory()
    except Exception as error:
        return f"{type(error).__name__}: {error}"
    return None


def failure_message(exc: BaseException) -> str:
    """A failed job's message: the error first (what a user reads in the trial), then
    the traceback's tail."""
    head = f"{type(exc).__name__}: {exc}"
    tail = "".join(traceback.format_exception(exc)[-6:])
    return (head + "\n\n" + tail)[:MESSAGE_LIMIT]
