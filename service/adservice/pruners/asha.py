"""Asynchronous successive halving (Li et al., 2020; Optuna's SuccessiveHalvingPruner).

Rung k sits at ``min_resource * reduction_factor ** (min_early_stopping_rate + k)``
steps. A trial's value at a rung is its first report at or past the rung's step. When a
report takes a trial past one or more rungs, it goes on only if at each its value is
among the top ``1 / reduction_factor`` of the values every trial of the study (any
state) has reached there, itself included; a rung with ``bootstrap_count`` or fewer
values stops the trial. Promotion is asynchronous: a trial is never held back waiting
for others to reach its rung.

With ``promotion`` a stopped trial is paused rather than pruned, waiting at its rung
(:func:`waiting_rung`); it is promoted once it :func:`qualifies` there among the values
more trials have brought since (``adservice.repository.promotion``)."""

from __future__ import annotations

from collections.abc import Iterable, Iterator

from adclient.pruning import AshaOptions
from adservice.pruners.base import Curve, PruneRequest


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


def qualifies(options: AshaOptions, value: float, competing: list[float]) -> bool:
    """Whether ``value`` goes on from a rung whose values are ``competing`` (it among
    them): the rung has more than ``bootstrap_count`` values and it is in their top."""
    return len(competing) > options.bootstrap_count and promotable(
        value, competing, options.reduction_factor
    )


def rung_values(rung: int, curves: Iterable[Curve]) -> list[float]:
    """Every curve's value at ``rung``: its first report at or past it."""
    values = (curve.first_at_or_after(rung) for curve in curves)
    return [value for value in values if value is not None]


def waiting_rung(options: AshaOptions, step: int) -> int | None:
    """The rung a trial stopped at ``step`` waits at: the highest one at or below it."""
    passed = list(rungs(options, above=-1, up_to=step))
    return passed[-1] if passed else None


def asha_should_stop(options: AshaOptions, request: PruneRequest) -> bool:
    for rung in rungs(options, above=request.last_step_before, up_to=request.step):
        competing = [*rung_values(rung, request.others), request.value]
        if not qualifies(options, request.value, competing):
            return True
    return False
