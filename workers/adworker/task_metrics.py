"""A task's own metrics (a reach task's final tip distance), checked and merged into
its trial's.

After each evaluation episode the worker asks the environment for its task's metrics
of that episode (``env.task_metrics()``: on adworker's simulator, the task's
``metrics(snapshot)`` hook given the episode's last snapshot). A task's code is a
plugin's, and what it returns is checked by a whitelist (:func:`checked_task_metrics`):
a mapping of at most :data:`MAX_TASK_METRICS` names matching :data:`TASK_METRIC_NAME`
to finite numbers. Anything else fails the job with a message naming the first name or
value that is wrong; nothing is reported.

The trial reports each one as ``task.<name>`` (:data:`TASK_METRIC_PREFIX`), the mean
over the evaluation episodes that reported it, beside the worker's own metrics (``mass``,
``effort``, ``time_*``...), none of which starts so; a study whose catalogue is named
``task`` reports ``task.<entry>`` itself, and a task metric of the same name fails the
job rather than replace it (:func:`merge_task_metrics`).
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence

import numpy as np

TASK_METRIC_PREFIX = "task."
TASK_METRIC_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,63}")
"""A task metric's name: a letter, then up to 63 letters, digits and underscores."""
MAX_TASK_METRICS = 32


def checked_task_metrics(values: object) -> dict[str, float]:
    """A task's metrics of one episode as floats; ValueError naming the first name or
    value that is not allowed."""
    if not isinstance(values, Mapping):
        raise ValueError(
            f"a task's metrics are a mapping of names to numbers, got {type(values).__name__}"
        )
    if len(values) > MAX_TASK_METRICS:
        raise ValueError(f"a task reports at most {MAX_TASK_METRICS} metrics, got {len(values)}")
    checked: dict[str, float] = {}
    for name, value in values.items():
        if not isinstance(name, str) or TASK_METRIC_NAME.fullmatch(name) is None:
            raise ValueError(
                f"task metric name {str(name)[:80]!r} must match {TASK_METRIC_NAME.pattern}"
            )
        if isinstance(value, bool) or not isinstance(value, int | float | np.number):
            raise ValueError(f"task metric {name!r} must be a number, got {type(value).__name__}")
        number = float(value)
        if not math.isfinite(number):
            raise ValueError(f"task metric {name!r} must be finite, got {number}")
        checked[name] = number
    return checked


def merge_task_metrics(
    metrics: dict[str, float], episodes: Sequence[Mapping[str, float]]
) -> dict[str, float]:
    """``metrics`` with each task metric of ``episodes`` (checked ones) added as
    ``task.<name>``: its mean over the episodes that reported it. ValueError when the
    name is already one of ``metrics`` (a catalogue named ``task``)."""
    merged = dict(metrics)
    names = list(dict.fromkeys(name for episode in episodes for name in episode))
    for name in names:
        key = TASK_METRIC_PREFIX + name
        if key in metrics:
            raise ValueError(
                f"task metric {name!r} is reported as {key!r}, a metric the trial already has "
                "(the study's catalogue 'task'): rename the catalogue or the metric"
            )
        merged[key] = float(np.mean([episode[name] for episode in episodes if name in episode]))
    return merged
