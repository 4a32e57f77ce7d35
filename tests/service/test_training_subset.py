"""Past ``max_train`` observations qEI's model trains on a subset (issue 37): the best,
those nearest the best, and a seeded random rest; every observation below it."""

from __future__ import annotations

import numpy as np

from adservice.proposers.subset import training_subset


def test_below_the_limit_every_observation_is_kept() -> None:
    Z = np.random.default_rng(0).random((100, 3))
    assert training_subset(Z, Z[:, 0], limit=100, seed=1, n_issued=100) is None


def test_the_subset_keeps_the_best_and_their_neighbourhood_and_is_seeded() -> None:
    rng = np.random.default_rng(1)
    Z = rng.random((5000, 4))
    y = -np.sum((Z - 0.7) ** 2, axis=1)
    kept = training_subset(Z, y, limit=400, seed=3, n_issued=5000)
    assert kept is not None
    assert len(kept) == 400 and len(np.unique(kept)) == 400
    assert np.all(np.diff(kept) > 0)  # trial order kept
    best = set(np.argsort(-y)[:100])
    assert best <= set(kept)
    nearest_best = np.argsort(np.linalg.norm(Z - Z[np.argmax(y)], axis=1))[:150]
    assert set(nearest_best) <= set(kept)
    # The random rest covers the box: far from the best too.
    far = np.linalg.norm(Z[kept] - Z[np.argmax(y)], axis=1) > 0.8
    assert far.sum() > 20
    assert np.array_equal(kept, training_subset(Z, y, limit=400, seed=3, n_issued=5000))
    other = training_subset(Z, y, limit=400, seed=4, n_issued=5000)
    assert other is not None and not np.array_equal(kept, other)


def test_a_history_of_one_value_still_subsets() -> None:
    Z = np.random.default_rng(2).random((2000, 2))
    kept = training_subset(Z, np.zeros(2000), limit=64, seed=0, n_issued=2000)
    assert kept is not None and len(kept) == 64


def test_with_several_objectives_the_observed_front_is_kept() -> None:
    from adservice.proposers.multiobjective import observed_front

    rng = np.random.default_rng(4)
    Z = rng.random((3000, 2))
    small = observed_front(Z, np.ones(3000, dtype=bool))  # both maximised: a corner
    assert 3 < len(small) < 64
    kept = training_subset(Z, Z[:, 0], limit=256, seed=0, n_issued=3000, front=small)
    assert kept is not None and len(kept) == 256
    assert set(small) <= set(kept)
    # A front larger than half the subset: its best half by the first objective.
    trade_off = np.column_stack([Z[:, 0], 1.0 - Z[:, 0] ** 2 + 0.01 * Z[:, 1]])
    large = observed_front(trade_off, np.ones(3000, dtype=bool))
    assert len(large) > 128
    kept = training_subset(Z, trade_off[:, 0], limit=256, seed=0, n_issued=3000, front=large)
    assert kept is not None and len(kept) == 256
    best_half = large[np.argsort(-trade_off[large, 0])][:128]
    assert set(best_half) <= set(kept)


def test_the_subset_is_the_most_the_memory_budget_holds() -> None:
    from adservice.proposers.subset import MAX_TRAIN, MIN_TRAIN, train_size

    def need(n: int) -> int:
        return 100 * n * n

    assert train_size(need, None) == MAX_TRAIN
    assert train_size(need, need(MAX_TRAIN)) == MAX_TRAIN
    fits = train_size(need, 100 * 2000 * 2000)
    assert fits == 2000 and need(fits + 1) > 100 * 2000 * 2000
    assert train_size(need, 1) == MIN_TRAIN  # the ask's memory check then falls back
