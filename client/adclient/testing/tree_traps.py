"""Floor traps (issue 61): design objectives where a tree's first random design says
almost nothing, for bench/design_suite.py and the proposer's tests.

Every tree's score is ``ceiling * fit * (0.3 + 0.7 * alignment)`` with a floor of 0
(``fit`` a Gaussian bump of the links' lengths, as ``design_objectives.spec_dominated``).
The best tree (ceiling 1) has an optimum narrow enough that a random design of it
lands near the floor more often than not, yet wide enough that random search, a few
designs of it in 30, finds it on most seeds; every other tree tops out at
``OTHERS_CEILING`` or lower, on a broad plateau, so its random design looks at least as
good as the best tree's. A search that ranks the trees by one design each, or that
learns the output scale from the low values it has seen and so cannot imagine a tree
reaching far above them, refines a wrong tree and ends under random search's lower
quartile (issue 61's seed: the start's eight designs scored 0.109 and 0 to 0.03, and
every later ask refined the 0.109 tree).

- ``floor-8``: the 8-tree, 13-spec space of the suite.
- ``floor-16``: every tree of 4 links (16), lengths and radii.
- ``needle-floor-32`` and ``needle-floor-64``: 32 and 64 trees of 5 links, one tree far
  better than the rest (a needle), unrelated to how alike the trees are.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from adclient.design import DesignSpace
from adclient.designs import Design
from adclient.testing.design_objectives import (
    LIMBS5_STRUCTURES,
    SpecDominated,
    _alignment,
    _lengths,
    _unit,
    all_trees_space,
    limbs5_space,
)

OTHERS_CEILING = 0.3
"""The most a design of any tree but the best scores."""
PLATEAU_POWER = 3.0
"""The best tree's fit is ``exp(-(misfit / 2 w^2) ** PLATEAU_POWER)``."""


def floor_trap(
    layout_seed: int, count: int, best_width: float, others_width: tuple[float, float]
) -> SpecDominated:
    """``count`` trees; the best (drawn from ``layout_seed``) of ceiling 1 and width
    ``best_width`` (root-mean-square length distance), the others of ceilings 0.1 to
    ``OTHERS_CEILING`` and widths in ``others_width``; each tree's optimal lengths and
    axes its own draw."""
    rng = np.random.default_rng([961, layout_seed])
    best = int(rng.integers(count))
    ceilings = rng.uniform(0.1, OTHERS_CEILING, size=count)
    widths = rng.uniform(*others_width, size=count)
    ceilings[best], widths[best] = 1.0, best_width
    per_tree = [
        (
            {name: float(rng.uniform(0.15, 0.45)) for name in "abcde"},
            {name: _unit(rng) for name in "bcde"},
        )
        for _ in range(count)
    ]

    def score(design: Design) -> float:
        tree = design.structure_index
        lengths, axes = per_tree[tree]
        own = _lengths(design)
        misfit = sum((own[k] - lengths[k]) ** 2 for k in own) / len(own)
        # the best tree's bump is flat-topped (a plateau with steep sides): its random
        # designs land either near the floor or high, rarely between
        power = PLATEAU_POWER if tree == best else 1.0
        fit = np.exp(-((misfit / (2.0 * widths[tree] ** 2)) ** power))
        return float(ceilings[tree] * fit * (0.3 + 0.7 * _alignment(design, axes)))

    return SpecDominated(score, tuple(float(c) for c in ceilings), best)


def many_trees_space(count: int, seed: int) -> dict[str, Any]:
    """``count`` of the 125 trees of 5 links, drawn from ``seed``; designs whose links
    meet at the rest pose are scored too (``allow_overlaps``: a synthetic score, and many
    trees of 5 links of one radius fold siblings through each other at rest, so without
    it the server refuses the space)."""
    space = {**all_trees_space("abcde", radius=False), "allow_overlaps": True}
    trees = DesignSpace.model_validate({**space, "max_structures": 1000}).tree_structures()
    chosen = sorted(np.random.default_rng([962, seed]).choice(len(trees), count, replace=False))
    space["structures"] = [[list(edge) for edge in trees[int(k)]] for k in chosen]
    return space


FLOOR_TRAPS: dict[str, tuple[dict[str, Any], SpecDominated]] = {
    "floor-8": (limbs5_space(), floor_trap(1, len(LIMBS5_STRUCTURES), 0.11, (0.12, 0.25))),
    "floor-16": (all_trees_space("abcd", radius=True), floor_trap(2, 16, 0.09, (0.12, 0.25))),
    "needle-floor-32": (many_trees_space(32, 3), floor_trap(3, 32, 0.1, (0.12, 0.25))),
    "needle-floor-64": (many_trees_space(64, 4), floor_trap(4, 64, 0.1, (0.12, 0.25))),
}
"""Each floor trap's design space and objective."""
