"""The trial's ``curve.json``, written through its contract (:class:`adclient.schemas.Curve`),
and the words for what an evaluation episode's score is: the rule the task declares
beside its ``score`` (``Task.score_rule``, read through the env's ``score_text``), so the
text says what the number is (walk-forward's last value, not a second-half mean) without
guessing it from what the rule computes."""

from __future__ import annotations

import math
from collections.abc import Sequence

from adclient.schemas import Curve, EvaluationEpisode, Job, TrainPoint
from adworker.learners import EpisodeResult
from adworker.starts import TrainResult

UNDECLARED = "the env's episode score"
"""The words for an env that does not say what its score is (a plugin's own env without
a ``score_text``)."""


def env_score_text(env: object) -> str:
    """What an episode's score is on ``env``: its ``score_text`` (a ``RobotEnv``'s: its
    task's declared rule), else :data:`UNDECLARED`."""
    text = getattr(env, "score_text", None)
    return text if isinstance(text, str) and text.strip() else UNDECLARED


def evaluation_score_text(rule_text: str) -> str:
    """The trial's value in words: the mean over its evaluation episodes of their score."""
    return f"mean over evaluation episodes of {rule_text}"


def evaluation_curve(
    job: Job, trained: TrainResult, episodes: Sequence[EpisodeResult], rule_text: str
) -> Curve:
    """A task job's curve: the learner's training points (those with a finite score) and
    the evaluation episodes."""
    return Curve(
        trial_id=job.trial_id,
        task=job.task.name,
        learner=job.task.learner,
        score=evaluation_score_text(rule_text),
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
