"""The trial's ``curve.json``, written through its contract (:class:`adclient.schemas.Curve`),
and the words for what an evaluation episode's score is, taken from the rule the task's
env scores its episodes with, so the text says what the number is (walk-forward's last
value, not a second-half mean)."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

from adclient.schemas import Curve, EvaluationEpisode, Job, TrainPoint
from adworker.learners import EpisodeResult
from adworker.starts import TrainResult
from adworker.tasks.base import Task, episode_score

ScoreRule = Callable[[list[float]], float]

KNOWN_RULES: tuple[tuple[str, ScoreRule], ...] = (
    ("the per-step metric's second-half mean", episode_score),
    ("the per-step metric's last value (at the episode's end)", lambda m: m[-1]),
    ("the per-step metric's mean over the episode", lambda m: float(np.mean(m))),
    ("the per-step metric's largest value", max),
    ("the per-step metric's smallest value", min),
    ("the per-step metric's sum", lambda m: float(np.sum(m))),
)
"""Rules a task's score may follow, each in words."""

PROBES = ([0.5, 2.0, -1.0, 3.0, 1.25], [1.0, 4.0, 2.0, 8.0, -3.0, 0.5, 0.25])
"""Metrics on which every known rule gives another value than each other rule."""


def score_rule_text(score_of: ScoreRule | None) -> str:
    """What an episode's score is under ``score_of`` (the env's rule: its task's
    ``score``): the known rule it computes on every probe, else its docstring's first
    line, else its name."""
    if score_of is None:
        return "the env's episode score"
    try:
        results = [float(score_of(list(probe))) for probe in PROBES]
    except Exception:  # a plugin's rule that needs real episodes: described otherwise
        results = []
    for text, rule in KNOWN_RULES:
        if results and all(
            np.isclose(result, float(rule(list(probe))))
            for result, probe in zip(results, PROBES, strict=True)
        ):
            return text
    rule = getattr(score_of, "__func__", score_of)  # a task's bound ``score``
    doc = (getattr(rule, "__doc__", None) or "").strip()
    if doc and rule is not Task.score:
        return doc.splitlines()[0].rstrip(".")
    return f"the task's own score of its per-step metric ({getattr(rule, '__qualname__', rule)})"


def evaluation_score_text(score_of: ScoreRule | None) -> str:
    """The trial's value in words: the mean over its evaluation episodes of their score."""
    return f"mean over evaluation episodes of {score_rule_text(score_of)}"


def evaluation_curve(
    job: Job, trained: TrainResult, episodes: Sequence[EpisodeResult], score_of: ScoreRule | None
) -> Curve:
    """A task job's curve: the learner's training points (those with a finite score) and
    the evaluation episodes."""
    return Curve(
        trial_id=job.trial_id,
        task=job.task.name,
        learner=job.task.learner,
        score=evaluation_score_text(score_of),
        train_steps=float(trained.train_steps),
        train=[
            TrainPoint(steps=point["steps"], score=point["score"])
            for point in trained.curve
            if math.isfinite(point["score"])  # JSON has no NaN: a diverged episode is left out
        ],
        evaluation=[
            EvaluationEpisode(
                seed=episode.seed,
                score=episode.score,
                episode_return=episode.episode_return,
                metric=[round(value, 6) for value in episode.metric],
                task_metrics=episode.task_metrics,
            )
            for episode in episodes
        ],
    )
