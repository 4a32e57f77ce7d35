"""The no-physics task's score: what the load driver's simulated workers compute, and
what real ``adworker`` processes and Ray actors run under load
(``adworker --function adclient.testing.noop:score --task noop``). It imports nothing,
so a worker's cost is adworker's own loop (lease, tell) alone."""

from __future__ import annotations

from typing import Any


def score_params(params: dict[str, float]) -> float:
    """A cheap smooth function of the load study's two params."""
    return -((params["x"] - 0.5) ** 2) - (params["y"] + 0.25) ** 2


def score(job: Any) -> float:
    """``--function``'s callable: the job's params, scored."""
    return score_params(job.params)
