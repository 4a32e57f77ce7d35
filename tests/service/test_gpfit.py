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
