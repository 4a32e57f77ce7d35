"""qei's tree judgement: which structures of a design space seen only once deserve a
second look (``initial.second_look`` says when an ask is a look, this module which
trees it may choose among).

A tree's *chance* is the probability, under the fitted GP, that the best of the tree
beats the incumbent: the fraction of joint posterior draws over ``LOOK_POINTS`` of the
tree's designs (scrambled Sobol specs, plus the best observed designs' specs moved onto
the tree) whose largest value exceeds the incumbent. A judged look chooses among the
trees whose chance is at least ``initial.LOOK_CHANCE``; when none is, the ask is a free choice.
So where the first designs and the model rank the trees rightly, no ask is spent going
back; where the model cannot tell (a tree's designs are far from its best specs, or it
holds the trees unrelated), the tree gets its look.

Imported only when a proposal is computed (it imports torch).
"""

from __future__ import annotations

import numpy as np
import torch

from adservice.proposers.acquisition import MixedDomain, raw_samples
from adservice.proposers.posterior import Posterior

LOOK_POINTS = 64
"""Designs of a tree its best is drawn over (random specs, then the best designs' specs)."""
LOOK_DRAWS = 256
"""Joint posterior draws of those designs' values."""
LOOK_INCUMBENTS = 3
"""The best observed designs whose specs are also tried on each tree."""


def tree_chances(
    posterior: Posterior,
    domain: MixedDomain,
    trees: np.ndarray,
    best_known: np.ndarray,
    incumbent: float,
    seed: int,
    tkw: dict,
) -> np.ndarray:
    """Each of ``trees``' chance that its best beats ``incumbent`` (see the module
    docstring); ``best_known``: model inputs of the best observed designs, best first."""
    rng = np.random.default_rng([seed, 37])
    chances = np.zeros(len(trees))
    observed = posterior.points[:, 0].round().long().cpu().numpy()
    keep = ~np.isin(observed, trees)
    if keep.any():
        posterior = posterior.keeping(torch.as_tensor(keep, device=posterior.points.device))
    for k, tree in enumerate(trees):
        moved = best_known[:LOOK_INCUMBENTS].copy()
        moved[:, 0] = tree
        random = raw_samples(domain, LOOK_POINTS - len(moved), rng, np.array([tree]))
        points = np.concatenate([domain.canonical(moved), random])
        mean, covariance = joint_posterior(posterior, torch.as_tensor(points, **tkw))
        draws = sample_normal(mean, covariance, LOOK_DRAWS, rng)
        chances[k] = float(np.mean(draws.max(axis=1) > incumbent))
    return chances


def joint_posterior(posterior: Posterior, Z: torch.Tensor) -> tuple[np.ndarray, np.ndarray]:
    """The posterior mean and covariance (in the outcome's scale) of the rows of Z."""
    with torch.no_grad():
        embedded = posterior.kernel.embed(Z)
        cross = posterior.kernel.from_embeddings(embedded, posterior.embedded)
        mean = posterior.constant + cross @ posterior.alpha
        solved = torch.linalg.solve_triangular(posterior.cholesky, cross.T, upper=False)
        prior = posterior.kernel.from_embeddings(embedded, embedded)
        covariance = prior - solved.T @ solved
        scale = posterior.scale
        return (
            (posterior.offset + scale * mean).cpu().numpy(),
            (scale**2 * covariance).cpu().numpy(),
        )


def sample_normal(
    mean: np.ndarray, covariance: np.ndarray, count: int, rng: np.random.Generator
) -> np.ndarray:
    """``count`` draws (rows) of a multivariate normal, through its eigen-decomposition
    (a posterior covariance is often singular to rounding)."""
    values, vectors = np.linalg.eigh((covariance + covariance.T) / 2)
    root = vectors * np.sqrt(np.clip(values, 0.0, None))
    return mean + rng.standard_normal((count, len(mean))) @ root.T
