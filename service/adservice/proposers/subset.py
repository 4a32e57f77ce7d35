"""Which observations an exact GP trains on when a study has more than it can afford.

An exact GP's fit costs n^3 time and n^2 memory: past a few thousand observations an
ask would not fit the memory budget, and would take minutes. Past ``max_train``
observations (by default the most the ask's memory budget holds, ``train_size``, at
most ``MAX_TRAIN``, and on cpu at most ``CPU_TRAIN``) the model trains on a subset of
that size, chosen to keep what expected improvement over the whole box needs (past
``trust_region.TRUST_FROM`` observations of a continuous box, a trust region instead):

- the best quarter by the first outcome (the incumbent's neighbourhood in value; with
  several objectives, the observed Pareto front first, up to half),
- the quarter nearest the best point in model inputs (the trust region around it),
- the rest drawn at random, seeded by the study's seed and ``n_issued`` (the global
  trend, so the acquisition still sees where nothing good was found).

Every observation still counts where the model is not needed: duplicate checks,
pending and failed points, the count of distinct points. bench/RESULTS.md ("Asks past
thousands of observations") measures the cost in quality against the full fit.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from adservice.proposers.simple import derived_seed

MAX_TRAIN = 4096
"""Observations an ask's model trains on at most unless ``options.max_train`` says; fewer
when the ask's memory budget holds fewer (``train_size``)."""
CPU_TRAIN = 2048
"""On cpu, the most observations a GP trains on by default: a time bound (an exact ask of
2,000 to 3,000 observations took 3 to 6 s on two cores, bench/RESULTS.md)."""
MIN_TRAIN = 256
"""The smallest subset ``train_size`` offers: below it the ask falls back instead."""


def train_size(need: Callable[[int], int], budget: int | None, most: int = MAX_TRAIN) -> int:
    """The most observations (``MIN_TRAIN`` to ``most``) whose ask, by ``need`` (bytes
    for a number of training observations), fits ``budget`` bytes (None: no budget)."""
    if budget is None or need(most) <= budget:
        return most
    low, high = MIN_TRAIN, most
    if need(low) > budget:
        return low  # the ask's memory check falls back to Sobol points, saying why
    while high - low > 1:
        middle = (low + high) // 2
        low, high = (middle, high) if need(middle) <= budget else (low, middle)
    return low


def training_subset(
    Z: np.ndarray,
    first_outcome: np.ndarray,
    *,
    limit: int,
    seed: int,
    n_issued: int,
    front: np.ndarray | None = None,
) -> np.ndarray | None:
    """Indices (ascending) of at most ``limit`` observations to train on, or None to
    train on all. ``Z``: model inputs (n x k); ``first_outcome``: to be maximised. With
    several objectives, ``front`` (indices of the observed Pareto front) comes first
    among the best, so the hypervolume the acquisition improves on is the real one."""
    n = len(Z)
    if n <= limit:
        return None
    quarter = limit // 4
    chosen = np.zeros(n, dtype=bool)
    order = np.argsort(-first_outcome, kind="stable")
    if front is not None and len(front):
        kept_front = front[np.argsort(-first_outcome[front], kind="stable")][: limit // 2]
        chosen[kept_front] = True
        order = np.concatenate([kept_front, order[~np.isin(order, kept_front)]])
    chosen[order[: max(quarter, int(chosen.sum()))]] = True
    distance = np.linalg.norm(Z - Z[order[0]], axis=1)
    distance[chosen] = np.inf
    chosen[np.argsort(distance, kind="stable")[:quarter]] = True
    rest = np.flatnonzero(~chosen)
    rng = np.random.default_rng(derived_seed(seed, n_issued, 0x5B5E7))
    chosen[rng.choice(rest, size=limit - int(chosen.sum()), replace=False)] = True
    return np.flatnonzero(chosen)
