"""The contract of one training run: where a learner's training starts, what it
reports while it trains (:class:`Reporting`) and returns (:class:`TrainResult`, also
importable from :mod:`adworker.learners`), and calling a learner with it.

A learner's ``train(env, *, steps, seed, check, start, keep_checkpoint, reporting)``
(:class:`adworker.learners.Learner`) starts from one typed value: :class:`Scratch`,
:class:`Resume` (its own trial's paused state) or :class:`Warm` (another design's
controller). :func:`train_learner` calls a learner so, and still calls a plugin learner
written against the interface before (``train(env, *, steps, seed, check)`` configured
by attributes) for one release, with a DeprecationWarning (docs/plugins.md).
"""

from __future__ import annotations

import functools
import inspect
import logging
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Literal, cast

import numpy as np

Policy = Callable[[np.ndarray], np.ndarray]
log = logging.getLogger("adworker")


def no_check() -> None:
    """A ``check`` that never stops training."""
    return None


@dataclass
class TrainResult:
    policy: Policy
    train_steps: int
    curve: list[dict[str, float]] = field(default_factory=list)
    """One point per training episode (or candidate): steps so far and its score."""
    info: dict[str, Any] = field(default_factory=dict)
    checkpoint: bytes | None = None
    """The learner's final state, when the worker asked for it (``keep_checkpoint``)."""
    warm_started: bool = False
    """It trained on from its ``Warm`` start: another design's controller."""
    shared: dict[str, np.ndarray] | None = None
    """A ``Shared`` start's weights after training: this design's update of the study's
    shared controller."""
    shared_start: dict[str, np.ndarray] | None = None
    """The shared weights it started from (the given version's, or the study's initial
    ones): what its update is measured against when versions are merged."""


@dataclass
class Reporting:
    """Intermediate reports while a learner trains (a study with a pruner): every
    ``every`` steps the learner scores its current policy (``evaluate``: the task's
    evaluation episodes on an env of its own) and ``report``s it, which raises
    ``adworker.runner.Pruned`` when the study's pruner stops the trial there."""

    every: int
    evaluate: Callable[[Policy], float]
    report: Callable[[int, float], None]
    due: int = 0

    def __post_init__(self) -> None:
        self.due = self.every

    def resume_at(self, steps: int) -> None:
        """A resumed learner reports next at the first multiple of ``every`` past
        ``steps``, as it would have without the pause."""
        self.due = (steps // self.every + 1) * self.every

    def send(self, steps: int, value: float) -> None:
        self.resume_at(steps)
        self.report(steps, value)


@dataclass(frozen=True)
class Scratch:
    """Train from nothing: a fresh model of the job's own settings."""


@dataclass(frozen=True)
class Resume:
    """Train on from this trial's own state (a promoted trial): the checkpoint a learner
    that pauses attached to ``Pruned``, to the ``steps`` budget it was training to."""

    checkpoint: bytes


@dataclass(frozen=True)
class Warm:
    """Start from another design's controller (a study with ``task.transfer``): the
    checkpoint its learner returned, and the ``steps`` to train from there instead of
    the from-scratch budget. A learner that cannot use it (another observation or
    action space, a file that does not load) says why in ``Learner.warm_problem`` and
    trains from scratch to the budget."""

    checkpoint: bytes
    steps: int


@dataclass(frozen=True)
class Shared:
    """Start from the study's shared controller (``task.transfer: shared``): a policy
    whose weights fit every design of the study (:mod:`adworker.modular`). ``weights``:
    its current version's (:mod:`adworker.shared_weights`), or None before the first
    version or when that version does not load: then the study's initial weights,
    the same on every worker for ``seed``. Trains ``steps`` and returns its weights as
    ``TrainResult.shared`` (and those it started from as ``shared_start``).
    ``carries``: ``all`` (the default) trains from the version as it is; ``critic`` keeps
    the version's critic and starts the actor from the initial weights
    (``shared_start`` is still the version, so the update the study merges is this
    design's actor and its change to the critic)."""

    weights: dict[str, np.ndarray] | None
    steps: int
    seed: int
    version: int | None = None
    carries: Literal["critic", "all"] = "all"


Start = Scratch | Resume | Warm | Shared
"""Where a learner's training starts: one value, so a resume and a warm start can never
both be asked for."""

SCRATCH = Scratch()


def train_learner(
    learner: Any,
    env: Any,
    *,
    steps: int,
    seed: int,
    check: Callable[[], None] = no_check,
    start: Start = SCRATCH,
    keep_checkpoint: bool = False,
    reporting: Reporting | None = None,
) -> TrainResult:
    """``learner.train`` with the job's start, checkpoint wish and reporting as keyword
    arguments. A plugin learner written against the interface before them
    (``train(env, *, steps, seed, check)``, configured by attributes) still trains for
    this release, with a DeprecationWarning: its ``reporting``, ``resume_from`` (a
    ``Resume``'s bytes), ``warm_start`` (the ``Warm`` itself: ``checkpoint`` and
    ``steps``) and ``keep_checkpoint`` are set before it is called."""
    if _takes_start(learner.train):
        return cast(
            "TrainResult",
            learner.train(
                env,
                steps=steps,
                seed=seed,
                check=check,
                start=start,
                keep_checkpoint=keep_checkpoint,
                reporting=reporting,
            ),
        )
    message = (
        f"learner {type(learner).__name__}: train(env, *, steps, seed, check) configured by "
        "the attributes reporting, resume_from, warm_start and keep_checkpoint is "
        "deprecated and will stop working in the next release; accept train(env, *, "
        "steps, seed, check, start, keep_checkpoint, reporting) instead (docs/plugins.md)"
    )
    warnings.warn(message, DeprecationWarning, stacklevel=2)
    _log_once(message)
    learner.reporting = reporting
    learner.resume_from = start.checkpoint if isinstance(start, Resume) else None
    learner.warm_start = start if isinstance(start, Warm) else None
    learner.keep_checkpoint = keep_checkpoint
    learner.warm_problem = None
    return cast("TrainResult", learner.train(env, steps=steps, seed=seed, check=check))


def from_attributes(
    learner: Any, start: Start | None, keep_checkpoint: bool | None, reporting: Reporting | None
) -> tuple[Start, bool, Reporting | None]:
    """A built-in learner's start, checkpoint wish and reporting: as given, or, where
    ``start`` is None (an attribute-configured plugin subclass calling
    ``super().train(env, steps=, seed=, check=)``), from the attributes
    :func:`train_learner` set on it for this release, so its resume or warm start is not
    silently dropped."""
    if start is None:
        resume = getattr(learner, "resume_from", None)
        warm = getattr(learner, "warm_start", None)
        start = (
            Resume(resume) if resume is not None else warm if isinstance(warm, Warm) else SCRATCH
        )
    if keep_checkpoint is None:
        keep_checkpoint = bool(getattr(learner, "keep_checkpoint", False))
    if reporting is None:
        reporting = getattr(learner, "reporting", None)
    return start, keep_checkpoint, reporting


@functools.cache
def _log_once(message: str) -> None:
    """Log a deprecation once per worker process (Python hides DeprecationWarning from
    a program's own users unless asked)."""
    log.warning("%s", message)


def _takes_start(train: Callable[..., Any]) -> bool:
    """Whether a learner's ``train`` takes the ``start`` keyword (or any keyword)."""
    parameters = inspect.signature(train).parameters.values()
    return any(
        parameter.name == "start" or parameter.kind is inspect.Parameter.VAR_KEYWORD
        for parameter in parameters
    )
