"""qei's tree judgement: which structures of a design space deserve another look
(``initial.second_look`` and ``initial.thompson_turn`` say when an ask is a look, this
module which trees it may choose among).

``drawn_tree`` (``second_looks: thompson``, the default) is Thompson sampling across
trees: for every tree, one joint posterior draw over ``LOOK_POINTS`` of its designs
(each tree drawn on its own: the covariance between trees is left out), and the tree
whose drawn best is largest. A tree whose one design was poor by chance still
wins some draws, in proportion to how plausible it is that its best is the best.

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
    docstring); ``best_known``: model inputs of the best observed designs, best first.
    The posterior leaves out the observations of ``trees``; where every observation is
    of one of them (a start that did not cover the other trees) it keeps them all, as
    there is nothing else to judge by."""
    rng = np.random.default_rng([seed, 37])
    observed = posterior.points[:, 0].round().long().cpu().numpy()
    keep = ~np.isin(observed, trees)
    if keep.any():
        posterior = posterior.keeping(torch.as_tensor(keep, device=posterior.points.device))
    points, normals = [], []
    for tree in trees:
        points.append(_tree_designs(domain, int(tree), best_known, rng))
        normals.append(rng.standard_normal((LOOK_DRAWS, len(points[-1]))))
    blocks = joint_posterior(posterior, [torch.as_tensor(block, **tkw) for block in points])
    chances = np.zeros(len(trees))
    for k, ((mean, covariance), normal) in enumerate(zip(blocks, normals, strict=True)):
        draws = mean + normal @ covariance_root(covariance).T
        chances[k] = float(np.mean(draws.max(axis=1) > incumbent))
    return chances


def drawn_tree(
    posterior: Posterior,
    domain: MixedDomain,
    trees: np.ndarray,
    best_known: np.ndarray,
    seed: int,
    tkw: dict,
) -> int:
    """The tree of ``trees`` whose best is largest in one joint posterior draw of each
    tree's values over its ``LOOK_POINTS`` designs (``tree_chances``'s designs; each tree
    drawn on its own, every observation kept)."""
    rng = np.random.default_rng([seed, 38])
    points = [_tree_designs(domain, int(tree), best_known, rng) for tree in trees]
    blocks = joint_posterior(posterior, [torch.as_tensor(block, **tkw) for block in points])
    best = [
        float((mean + covariance_root(covariance) @ rng.standard_normal(len(mean))).max())
        for mean, covariance in blocks
    ]
    return int(trees[int(np.argmax(best))])


def _tree_designs(
    domain: MixedDomain, tree: int, best_known: np.ndarray, rng: np.random.Generator
) -> np.ndarray:
    """``LOOK_POINTS`` designs of ``tree`` (model inputs, canonical): the best observed
    designs' specs moved onto it, then random specs."""
    moved = best_known[:LOOK_INCUMBENTS].copy()
    moved[:, 0] = tree
    random = raw_samples(domain, LOOK_POINTS - len(moved), rng, np.array([tree]))
    return np.concatenate([domain.canonical(moved), random])


def joint_posterior(
    posterior: Posterior, blocks: list[torch.Tensor]
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Each block of points' posterior mean and covariance (in the outcome's scale), the
    blocks' cross-covariances left out."""
    kernel = posterior.kernel
    with torch.no_grad():
        Z = torch.cat(blocks)
        cross = kernel.from_embeddings(kernel.embed(Z), posterior.embedded)
        mean = posterior.offset + posterior.scale * (posterior.constant + cross @ posterior.alpha)
        solved = torch.linalg.solve_triangular(posterior.cholesky, cross.T, upper=False)
        out, start = [], 0
        for block in blocks:
            part = slice(start, start + len(block))
            start = part.stop
            embedded = kernel.embed(block)
            prior = kernel.from_embeddings(embedded, embedded)
            covariance = posterior.scale**2 * (prior - solved[:, part].T @ solved[:, part])
            out.append((mean[part].cpu().numpy(), covariance.cpu().numpy()))
        return out


def covariance_root(covariance: np.ndarray) -> np.ndarray:
    """A matrix R with R R^T = ``covariance``, through its eigen-decomposition (a
    posterior covariance is often singular to rounding)."""
    values, vectors = np.linalg.eigh((covariance + covariance.T) / 2)
    return vectors * np.sqrt(np.clip(values, 0.0, None))
