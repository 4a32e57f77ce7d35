"""What a worker counts of its jobs: its rates for the log, and a trial's times summed
over its attempts."""

from __future__ import annotations

import time
from dataclasses import dataclass, field

from adclient.schemas import Job

TIMES = ("time_total_s", "time_cpu_s")
"""The metrics of a trial's time, summed over a paused trial's attempts."""


@dataclass
class Rates:
    """Running totals for the log's rates."""

    started: float = field(default_factory=time.monotonic)
    jobs: int = 0
    failed: int = 0
    sim_steps: float = 0.0
    busy_seconds: float = 0.0

    def line(self) -> str:
        minutes = max(time.monotonic() - self.started, 1e-9) / 60
        line = f"{self.jobs} jobs ({self.failed} failed), {self.jobs / minutes:.1f} jobs/min"
        if self.sim_steps:
            line += f", {self.sim_steps / max(self.busy_seconds, 1e-9):,.0f} sim steps/s while busy"
        return line


def spent(job: Job, metrics: dict[str, float]) -> dict[str, float]:
    """A resumed job's times count its trial's attempts up to the pause too, so a trial's
    ``time_total_s`` and ``time_cpu_s`` are all it took; it says where it resumed, and
    a warm-started trial keeps its ``transfer_*`` metrics."""
    if job.resume is None:
        return metrics
    earlier = job.resume.metrics
    return {
        **{key: value for key, value in earlier.items() if key.startswith("transfer_")},
        **metrics,
        **{key: metrics.get(key, 0.0) + earlier.get(key, 0.0) for key in TIMES},
        "resumed_from_step": float(job.resume.step),
    }
