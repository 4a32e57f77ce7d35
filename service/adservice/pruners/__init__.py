"""Pruners: should a running trial stop at the step it just reported?

Like the proposers, each pruner is pure: it sees arrays (the trial's curve, the other
trials' curves and states, values oriented so larger is better) and answers a bool; it
never touches the database or HTTP. ``adservice.services.reports`` gathers the arrays.
"""

from __future__ import annotations

from adclient.pruning import AshaOptions, MedianOptions, PrunerConfig
from adservice.pruners.asha import asha_should_stop
from adservice.pruners.base import Curve, PruneRequest
from adservice.pruners.median import median_should_stop

__all__ = ["Curve", "PruneRequest", "should_stop"]


def should_stop(config: PrunerConfig, request: PruneRequest) -> bool:
    """The decision of the study's pruner for one report."""
    options = config.parsed()
    if isinstance(options, MedianOptions):
        return median_should_stop(options, request)
    if isinstance(options, AshaOptions):
        return asha_should_stop(options, request)
    return False
