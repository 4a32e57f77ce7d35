"""Asynchronous successive halving (Li et al., 2020; Optuna's SuccessiveHalvingPruner).

Rung k sits at ``min_resource * reduction_factor ** (min_early_stopping_rate + k)``
steps. A trial's value at a rung is its first report at or past the rung's step. When a
report takes a trial past one or more rungs, it goes on only if at each its value is
among the top ``1 / reduction_factor`` of the values every trial of the study (any
state) has reached there, itself included; a rung with ``bootstrap_count`` or fewer
values stops the trial. Promotion is asynchronous: a trial is never held back waiting
for others to reach its rung."""

from __future__ import annotations

from collections.abc import Iterator

from adclient.pruning import AshaOptions
from adservice.pruners.base import PruneRequest


def rungs(options: AshaOptions, *, above: int, up_to: int) -> Iterator[int]:
    """The rung steps in ``(above, up_to]`` (below ``max_resource`` when it is set)."""
    rate = options.min_early_stopping_rate
    while True:
        step = options.min_resource * options.reduction_factor**rate
        if step > up_to or (options.max_resource is not None and step >= options.max_resource):
            return
        if step > above:
            yield step
        rate += 1


def promotable(value: float, competing: list[float], reduction_factor: int) -> bool:
    """Whether ``value`` is in the top ``1/reduction_factor`` of ``competing`` (which
    holds it), as Optuna decides: at least as good as the ``n // rf``-th best (the best
    when fewer than ``rf`` compete)."""
    ranked = sorted(competing, reverse=True)
    index = max(len(ranked) // reduction_factor - 1, 0)
    return value >= ranked[index]


def asha_should_stop(options: AshaOptions, request: PruneRequest) -> bool:
    for rung in rungs(options, above=request.last_step_before, up_to=request.step):
        competing = [
            value
            for value in (curve.first_at_or_after(rung) for curve in request.others)
            if value is not None
        ]
        competing.append(request.value)
        if len(competing) <= options.bootstrap_count:
            return True
        if not promotable(request.value, competing, options.reduction_factor):
            return True
    return False
