"""A trial's learning curve: the ``curve.json`` artifact a worker uploads, one contract for
the worker that writes it, the dashboard that draws it and the SDK that reads it.

The worker writes its training points (one per training episode, or candidate, of the
learner: the steps trained so far and that episode's score) and each evaluation
episode of the trained policy (its seed, score, return and per-step metric); ``score``
says in words what an evaluation episode's score is, as the task computes it. A
``--function`` job's reported values (``job.report``) are its training points.
"""

from __future__ import annotations

from typing import Any

from pydantic import AliasChoices, BaseModel, Field, model_validator

CURVE_ARTIFACT = "curve.json"
"""The artifact name a worker uploads the curve as."""


class TrainPoint(BaseModel):
    """One training episode (or candidate, or reported value) of the learner."""

    steps: float = Field(description="env steps trained when it ended")
    score: float = Field(description="its score (a function's reported value)")


class EvaluationEpisode(BaseModel):
    """One deterministic episode of the trained policy; the trial's value is the mean of
    their scores."""

    seed: int
    score: float
    episode_return: float = Field(
        validation_alias=AliasChoices("return", "episode_return"),
        serialization_alias="return",
        description="the sum of its rewards (``return`` in the file)",
    )
    metric: list[float] = Field(default_factory=list, description="the task's per-step metric")
    task_metrics: dict[str, float] = Field(
        default_factory=dict, description="the task's own metrics of the episode"
    )


class Curve(BaseModel):
    """``curve.json``: how the trial's controller learned and how it scored."""

    trial_id: int | None = None
    task: str | None = None
    learner: str | None = None
    score: str | None = Field(
        default=None, description="what an evaluation episode's score is, as the task computes it"
    )
    train_steps: float | None = Field(
        default=None, description="the steps trained before the evaluation episodes"
    )
    train: list[TrainPoint] = Field(default_factory=list)
    evaluation: list[EvaluationEpisode] = Field(default_factory=list)

    @model_validator(mode="before")
    @classmethod
    def _earlier_shape(cls, data: Any) -> Any:
        """The shape a ``--function`` job's curve had before this contract,
        ``{"steps": [...], "y": [...]}``: stored trials keep their curves."""
        if isinstance(data, dict) and set(data) == {"steps", "y"}:
            steps, values = data["steps"], data["y"]
            if isinstance(steps, list) and isinstance(values, list) and len(steps) == len(values):
                pairs = zip(steps, values, strict=True)
                return {"train": [{"steps": step, "score": value} for step, value in pairs]}
        return data

    def to_json(self) -> bytes:
        """The artifact's bytes, compact."""
        return self.model_dump_json(by_alias=True, exclude_none=True).encode()
