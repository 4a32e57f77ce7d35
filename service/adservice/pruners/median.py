"""Optuna's MedianPruner (a PercentilePruner at 50).

Stop a trial when its best value so far is worse than the median of the complete
trials' values at the same step; never before ``n_startup_trials`` complete trials,
before ``n_warmup_steps``, or between pruning steps (``n_warmup_steps + k *
interval_steps``: a check happens on the first report at or past each)."""

from __future__ import annotations

import numpy as np

from adclient.pruning import MedianOptions
from adservice.pruners.base import PruneRequest


def first_in_interval(request: PruneRequest, options: MedianOptions) -> bool:
    """Whether this report is the trial's first at or past its latest pruning step."""
    offset = request.step - options.n_warmup_steps
    nearest_lower = offset // options.interval_steps * options.interval_steps
    return request.last_step_before < nearest_lower + options.n_warmup_steps


def median_should_stop(options: MedianOptions, request: PruneRequest) -> bool:
    complete = [curve for curve in request.others if curve.state == "complete"]
    if len(complete) < options.n_startup_trials or len(complete) == 0:
        return False
    if request.step < options.n_warmup_steps:
        return False
    if not first_in_interval(request, options):
        return False
    at_step = [v for v in (curve.value_at(request.step) for curve in complete) if v is not None]
    if len(at_step) < options.n_min_trials:
        return False
    return bool(request.best < float(np.median(at_step)))
