"""qei's structure search (issue 26): it covers the trees before it models them, it
keeps trying trees it knows little about, and its model keeps unseen trees uncertain.

The objective here is a trap: a tree's value adds to a spec term every tree shares,
so a wrong tree keeps scoring a little better as its specs improve, and the best tree
is the one the study's first designs are least likely to land on. Requests are built
by hand (no server); each study is a few dozen asks of the real proposer.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
import torch

from adclient.decode import decode
from adclient.design import DesignSpace
from adclient.designs import Design
from adservice.proposers import get_proposer
from adservice.proposers.base import ProposalRequest, empty_history, model_inputs
from adservice.proposers.gpfit import fit_outcome
from adservice.proposers.initial import structure_order
from adservice.proposers.posterior import Posterior
from adservice.proposers.qei_shared import QEIOptions
from adservice.representation import build_representation, search_structure

TKW: dict[str, Any] = {"dtype": torch.float64, "device": torch.device("cpu")}
CHAINS = [
    [["a", "b"]],
    [["a", "b"], ["b", "c"]],
    [["a", "b"], ["a", "c"]],
    [["a", "b"], ["b", "c"], ["c", "d"]],
    [["a", "b"], ["a", "c"], ["a", "d"]],
    [["a", "b"], ["b", "c"], ["b", "d"]],
]


def trap_space(structures: Any) -> DesignSpace:
    return DesignSpace.model_validate(
        {
            "type": "design",
            "parts": {"link": {"length": {"low": 0.1, "high": 0.5}, "radius": 0.04}},
            "joint": {"axis_theta": 1.5707963267948966, "axis_phi": 0.0},
            "instances": [{"name": name, "part": "link"} for name in "abcde"[: _size(structures)]],
            "structures": structures,
            "max_structures": 125,
            "reference_per_structure": 4,
        }
    )


def _size(structures: Any) -> int:
    return 5 if structures == "all" else 1 + max(len(edges) for edges in structures)


def trap_score(design: Design, best: int) -> float:
    """0.45 for the best tree, 0 to 0.3 for the others, plus up to 0.55 for a's and b's
    lengths (every tree has a and b)."""
    tree = 0.45 if design.structure_index == best else 0.3 * ((design.structure_index * 7) % 5) / 4
    lengths = {link.name: link.length for link in design.links}
    fit = math.exp(-((lengths["a"] - 0.35) ** 2 + (lengths["b"] - 0.2) ** 2) / 0.02)
    return tree + 0.55 * fit


def request(
    search: Any, bounds: np.ndarray, X: np.ndarray, y: np.ndarray, *, seed: int, count: int = 1
) -> ProposalRequest:
    return ProposalRequest(
        bounds=bounds,
        count=count,
        seed=seed,
        n_issued=len(y),
        X=X.reshape(-1, bounds.shape[1]),
        y=y,
        failed=empty_history(bounds.shape[1]),
        pending=empty_history(bounds.shape[1]),
        structure=search,
        options={"raw_samples": 512},
    )


def run_study(space: DesignSpace, best: int, evaluations: int, seed: int) -> list[int]:
    """The trees a qei study of ``evaluations`` asks proposes, in order."""
    representation = build_representation(space)
    search = search_structure(space, representation)
    bounds = np.asarray(representation.bounds, dtype=np.float64)
    proposer = get_proposer("qei")
    X: list[np.ndarray] = []
    y: list[float] = []
    trees: list[int] = []
    for _ in range(evaluations):
        asked = request(search, bounds, np.array(X), np.array(y), seed=seed)
        vector = proposer.propose(asked).candidates[0]
        design = decode(space, representation, vector)
        X.append(vector)
        y.append(trap_score(design, best))
        trees.append(design.structure_index)
    return trees


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 1])
def test_a_trap_study_tries_every_tree_and_settles_on_the_best(seed: int) -> None:
    """Six trees, the preprint's two-design start: the study still tries each tree (the
    old default kept to the first good one it met) and then spends its asks on the
    best, whichever tree its first designs landed on."""
    space = trap_space(CHAINS)
    best = 5
    trees = run_study(space, best, evaluations=14, seed=seed)
    assert set(trees) == set(range(len(CHAINS)))
    assert trees[len(CHAINS) :].count(best) >= 4, trees


def test_the_initial_design_spreads_over_more_trees_than_it_can_cover() -> None:
    """125 trees: the first 16 designs are 16 different trees, dealt farthest-first in the
    fused geometry, so they are farther apart than 16 trees drawn at random."""
    space = trap_space("all")
    representation = build_representation(space)
    search = search_structure(space, representation)
    assert search is not None and search.n_structures == 125
    order = structure_order(search, seed=3)
    assert sorted(order.tolist()) == list(range(125))
    coords = search.structure_coords

    def spread(indices: np.ndarray) -> float:
        points = coords[indices]
        gaps = np.linalg.norm(points[:, None] - points[None], axis=-1)
        return float(np.min(gaps[~np.eye(len(points), dtype=bool)]))

    random = [spread(np.random.default_rng(s).choice(125, 16, replace=False)) for s in range(20)]
    assert spread(order[:16]) > max(random)
    bounds = np.asarray(representation.bounds, dtype=np.float64)
    start = request(search, bounds, np.zeros(0), np.zeros(0), seed=3, count=16)
    proposal = get_proposer("qei").propose(start)
    assert proposal.candidates[:, 0].astype(int).tolist() == order[:16].tolist()
    assert {info["method"] for info in proposal.info} == {"sobol-initial"}


def test_trees_the_data_never_saw_stay_uncertain() -> None:
    """A history from two of six trees (an old study's, or designs enqueued by hand):
    at the incumbent's specs every unseen tree keeps a predictive standard deviation of
    at least half the observations' own, while the incumbent's tree is known there."""
    space = trap_space(CHAINS)
    representation = build_representation(space)
    search = search_structure(space, representation)
    assert search is not None
    bounds = np.asarray(representation.bounds, dtype=np.float64)
    rng = np.random.default_rng(0)
    X = bounds[0] + rng.random((24, bounds.shape[1])) * (bounds[1] - bounds[0])
    X[:, 0] = [3] * 23 + [1]
    y = np.array([trap_score(decode(space, representation, v), best=5) for v in X])
    history = request(search, bounds, X, y, seed=0)
    model, _ = fit_outcome(history, QEIOptions(), bounds, X, y, TKW, None)
    incumbent = X[np.argmax(y)]
    every_tree = np.repeat(incumbent[None], len(CHAINS), axis=0)
    every_tree[:, 0] = np.arange(len(CHAINS))
    Z = torch.as_tensor(model_inputs(every_tree, bounds, search), **TKW)
    with torch.no_grad():
        _, sigma = Posterior(model).mean_sigma(Z)
    unseen = [tree for tree in range(len(CHAINS)) if tree not in (1, 3)]
    assert float(sigma[unseen].min()) >= 0.5 * float(np.std(y)), sigma
    assert float(sigma[3]) < 0.5 * float(sigma[unseen].min()), sigma
