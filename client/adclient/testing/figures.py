"""A benchmark's figures as lines a comparison collects (bench/compare.py): each
``BENCH {"metric": ..., "value": ..., "higher_is_better": ..., "unit": ...}`` on stdout,
one per metric per run."""

from __future__ import annotations

import json

PREFIX = "BENCH "


def emit(metric: str, value: float, *, higher_is_better: bool, unit: str = "") -> None:
    """Print one result line for ``compare.py`` to collect (a bench script's last word)."""
    line = {"metric": metric, "value": value, "higher_is_better": higher_is_better, "unit": unit}
    print(PREFIX + json.dumps(line), flush=True)
