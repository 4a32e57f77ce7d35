"""What a pruner sees: curves as arrays, values oriented so that larger is better."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class Curve:
    """One trial's reports in order of step (``values`` oriented: larger is better)."""

    state: str
    steps: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    values: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def __post_init__(self) -> None:
        if self.steps.shape != self.values.shape:
            raise ValueError("a curve needs one value per step")

    def value_at(self, step: int) -> float | None:
        """The value reported at exactly ``step``."""
        index = np.searchsorted(self.steps, step)
        if index < len(self.steps) and self.steps[index] == step:
            return float(self.values[index])
        return None

    def first_at_or_after(self, step: int) -> float | None:
        """The value of the first report at ``step`` or later (a rung's value)."""
        index = np.searchsorted(self.steps, step)
        return float(self.values[index]) if index < len(self.steps) else None


@dataclass(frozen=True)
class PruneRequest:
    """One report to decide on.

    step, value: the report (value oriented). previous_steps: the trial's earlier
    reported steps (all below ``step``). best: the trial's best value so far, this
    report included. others: every other trial of the study that reported."""

    step: int
    value: float
    previous_steps: np.ndarray
    best: float
    others: list[Curve]

    @property
    def last_step_before(self) -> int:
        """The trial's last reported step before this one; -1 for its first report."""
        return int(self.previous_steps.max()) if len(self.previous_steps) else -1
