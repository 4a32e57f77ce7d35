"""qei's fit of a long history: hyperparameters from a subset, a posterior on all of it."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from adservice.proposers.base import ProposalRequest, empty_history, model_inputs
from adservice.proposers.gpfit import FIT_BEST, FIT_POINTS, clear_caches, fit_outcome, fit_subset
from adservice.proposers.posterior import Posterior
from adservice.proposers.qei_shared import QEIOptions

TKW: dict[str, Any] = {"dtype": torch.float64, "device": torch.device("cpu")}


def history(n: int) -> tuple[ProposalRequest, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(n)
    bounds = np.array([[0.0] * 3, [1.0] * 3])
    X = rng.random((n, 3))
    y = np.sin(4 * X[:, 0]) + X[:, 1] ** 2 - X[:, 2]
    request = ProposalRequest(
        bounds=bounds,
        count=1,
        seed=5,
        n_issued=n,
        X=X,
        y=y,
        failed=empty_history(3),
        pending=empty_history(3),
    )
    return request, X, y


def test_the_subset_keeps_the_best_and_is_seeded() -> None:
    y = np.random.default_rng(0).random(1000)
    subset = fit_subset(y, seed=5)
    assert subset is not None and len(subset) == FIT_POINTS == len(set(subset.tolist()))
    assert set(np.argsort(-y)[:FIT_BEST].tolist()) <= set(subset.tolist())
    assert subset.tolist() == fit_subset(y, seed=5).tolist()  # type: ignore[union-attr]
    assert subset.tolist() != fit_subset(y, seed=6).tolist()  # type: ignore[union-attr]
    assert fit_subset(y[:FIT_POINTS], seed=5) is None


def test_a_long_history_is_fitted_on_a_subset_and_conditioned_on_all_of_it() -> None:
    clear_caches()
    request, X, y = history(FIT_POINTS + 200)
    model, source = fit_outcome(request, QEIOptions(), request.bounds, X, y, TKW, None)
    assert source == f"cold-subset-{FIT_POINTS}"
    assert len(model.train_targets) == len(y)
    posterior = Posterior(model)
    with torch.no_grad():
        mean, _ = posterior.mean_sigma(
            torch.as_tensor(model_inputs(X, request.bounds, None), **TKW)
        )
    # the observations left out of the fit are still interpolated (noise-free study)
    left_out = np.setdiff1d(np.arange(len(y)), fit_subset(y, request.seed))  # type: ignore[arg-type]
    assert np.max(np.abs(mean.numpy()[left_out] - y[left_out])) < 0.01 * np.ptp(y)


def test_a_short_history_is_fitted_on_every_observation() -> None:
    clear_caches()
    request, X, y = history(40)
    _, source = fit_outcome(request, QEIOptions(), request.bounds, X, y, TKW, None)
    assert source == "cold"


def test_the_fit_subset_stays_as_the_history_grows() -> None:
    y = np.random.default_rng(1).random(1000)
    subset = fit_subset(y, seed=5)
    assert subset is not None
    # a new observation below the best keeps every earlier one's place in or out
    grown = fit_subset(np.append(y, np.sort(y)[len(y) // 2]), seed=5)
    assert grown is not None and len(grown) == FIT_POINTS
    assert len(np.setdiff1d(subset, grown)) <= 1
    # a new best observation joins, and pushes out at most one other
    best = fit_subset(np.append(y, y.max() + 1.0), seed=5)
    assert best is not None and len(y) in best.tolist()
    assert len(np.setdiff1d(subset, best)) == 1


def test_a_training_subset_is_fitted_on_the_histories_sample() -> None:
    """With ``history`` (a model of a training subset), the fit is of ``fit_subset`` of
    the whole history: another training subset of the same history re-uses it, and a
    longer history warm-starts from it."""
    clear_caches()
    request, X, y = history(1200)
    options, bounds = QEIOptions(), request.bounds
    rng = np.random.default_rng(2)
    subsets = [np.sort(rng.choice(len(y), 600, replace=False)) for _ in range(2)]
    first = fit_outcome(
        request, options, bounds, X[subsets[0]], y[subsets[0]], TKW, None, history=(X, y)
    )
    assert first[1] == f"cold-subset-{FIT_POINTS}"
    second = fit_outcome(
        request, options, bounds, X[subsets[1]], y[subsets[1]], TKW, None, history=(X, y)
    )
    assert second[1] == "cached"
    assert len(second[0].train_targets) == 600
    lengthscales = [m.covar_module.spec.lengthscale.detach() for m in (first[0], second[0])]
    assert torch.equal(*lengthscales)
    # without the history each training subset's own sample is fitted, cold: another
    # subset's first rows are another study to the warm-start cache
    clear_caches()
    alone = [
        fit_outcome(request, options, bounds, X[rows], y[rows], TKW, None)[1] for rows in subsets
    ]
    assert alone == [f"cold-subset-{FIT_POINTS}"] * 2
    clear_caches()
    fit_outcome(request, options, bounds, X[:600], y[:600], TKW, None, history=(X, y))
    longer = (np.vstack([X, X[:1] * 0.5]), np.append(y, y.max() + 1.0))
    grown = fit_outcome(request, options, bounds, X[:600], y[:600], TKW, None, history=longer)
    assert grown[1] == f"warm-subset-{FIT_POINTS}"


def test_a_training_subsets_fit_takes_half_its_rest_from_the_good() -> None:
    y = np.random.default_rng(3).random(5000)
    rank = np.argsort(np.argsort(-y))
    plain, good = fit_subset(y, seed=5), fit_subset(y, seed=5, good=1024)
    assert plain is not None and good is not None and len(good) == FIT_POINTS
    half = (FIT_POINTS - FIT_BEST) // 2
    assert int((rank[good] < 1024).sum()) == FIT_BEST + half
    assert int((rank[plain] < 1024).sum()) < FIT_BEST + half // 2
    grown = fit_subset(np.append(y, np.median(y)), seed=5, good=1024)
    assert grown is not None and len(np.setdiff1d(good, grown)) <= 2
