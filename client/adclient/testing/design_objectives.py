"""The design suite's synthetic objectives (bench/design_suite.py runs them).

Each objective scores a decoded robot design (tree + specs) in [0, 1], so every method
optimises the identical function of the design.

Multiplicative families (issue 12): a wrong tree scores low whatever its specs.

- ``tree-similarity`` (8 trees of 3 to 5 links, 13 specs): the score falls with the
  tree's edit distance (edges added or removed) to a target tree, times how well the
  lengths and joint axes match targets. Structure similarity matters strongly.
- ``specs-only`` (the same space): only specs every tree has count (the lengths of a
  and b, the axis of b); the tree does not matter at all.
- ``unused-specs`` (the same space): the best trees are the ones with limb e, and
  then e's length and axis decide; the other trees only get a weaker score from b.
  The specs that matter are unused by half of the trees.
- ``interaction`` (4 trees of 4 links, lengths, radii and axes: 14 specs): every tree
  has its own optimal lengths and axes and its own ceiling; nothing carries over.

Additive families (issue 26): a tree's value adds to a spec term, so a wrong tree keeps
scoring a little better as its specs improve, the trap of a search that believes the
trees it has not seen behave like the ones it has (see the functions' docstrings).

- ``additive-trap`` (the 8-tree space): the best tree is the smallest, a-b-c.
- ``shifted-optima`` (the 8-tree space): each tree's best specs lie near, not at, a
  shared optimum; the best tree is the star a-(b, c, d).
- ``needle-16`` (every tree of 4 links: 16, 14 specs): one tree far better, unrelated
  to how alike the trees are.
- ``tree-shape-64`` (64 of the 125 trees of 5 links): the tree's value follows its
  shape (depth, leaves, root degree), so alike trees score alike.

Spec-dominated families (issue 37): the specs decide more than the tree; the best
tree's optimum is narrow, so its one random design scores poorly, and a decoy's is
broad (``spec_dominated``).

- ``spec-dominated-1`` to ``-4`` (the 8-tree space): four layouts and widths; the
  other trees' optima lie between the best's and the decoy's in width.
- ``spec-dominated-5`` and ``-6``: as issue 37's trap, every other tree narrow too and
  the decoy's plateau low.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from adclient.design import DesignSpace
from adclient.designs import Design

PI = math.pi

LIMBS5_STRUCTURES = [
    [["a", "b"], ["b", "c"]],
    [["a", "b"], ["b", "c"], ["c", "d"]],
    [["a", "b"], ["b", "c"], ["c", "d"], ["d", "e"]],
    [["a", "b"], ["b", "c"], ["b", "d"]],
    [["a", "b"], ["a", "c"], ["a", "d"]],
    [["a", "b"], ["b", "c"], ["c", "e"]],
    [["a", "b"], ["b", "c"], ["b", "d"], ["b", "e"]],
    [["a", "b"], ["b", "c"], ["c", "d"], ["c", "e"]],
]
ARMS4_STRUCTURES = [
    [["a", "b"], ["b", "c"], ["c", "d"]],
    [["a", "b"], ["a", "c"], ["a", "d"]],
    [["a", "b"], ["b", "c"], ["b", "d"]],
    [["a", "b"], ["a", "c"], ["c", "d"]],
]


def limbs5_space() -> dict[str, Any]:
    return {
        "type": "design",
        "parts": {"link": {"length": {"low": 0.1, "high": 0.5}, "radius": 0.04, "mass": 1.0}},
        "instances": [{"name": name, "part": "link"} for name in "abcde"],
        "structures": LIMBS5_STRUCTURES,
    }


def arms4_space() -> dict[str, Any]:
    return {
        "type": "design",
        "parts": {
            "link": {
                "length": {"low": 0.1, "high": 0.5},
                "radius": {"low": 0.02, "high": 0.08},
                "mass": 1.0,
            }
        },
        "instances": [{"name": name, "part": "link"} for name in "abcd"],
        "structures": ARMS4_STRUCTURES,
    }


def _unit(rng: np.random.Generator) -> np.ndarray:
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def _alignment(design: Design, targets: dict[str, np.ndarray]) -> float:
    """Mean squared cosine between each joint's axis and its target (sign-free)."""
    values = [
        float(np.dot(joint.axis, targets[joint.child])) ** 2
        for joint in design.joints
        if joint.child in targets
    ]
    return float(np.mean(values)) if values else 0.0


def _lengths(design: Design) -> dict[str, float]:
    return {link.name: link.length for link in design.links}


def tree_similarity() -> Callable[[Design], float]:
    rng = np.random.default_rng(101)
    target_edges = {tuple(edge) for edge in LIMBS5_STRUCTURES[2]}
    axes = {name: _unit(rng) for name in "bcde"}
    lengths = {name: float(rng.uniform(0.15, 0.45)) for name in "abcde"}

    def score(design: Design) -> float:
        edges = set(design.edges())
        structure = math.exp(-len(edges ^ target_edges) / 2.0)
        own = _lengths(design)
        fit = math.exp(-sum((own[k] - lengths[k]) ** 2 for k in own) / 0.05)
        return structure * fit * (0.3 + 0.7 * _alignment(design, axes))

    return score


def specs_only() -> Callable[[Design], float]:
    rng = np.random.default_rng(202)
    axis_b = _unit(rng)

    def score(design: Design) -> float:
        own = _lengths(design)
        fit = math.exp(-((own["a"] - 0.35) ** 2 + (own["b"] - 0.2) ** 2) / 0.02)
        return fit * (0.2 + 0.8 * _alignment(design, {"b": axis_b}))

    return score


def unused_specs() -> Callable[[Design], float]:
    rng = np.random.default_rng(303)
    axis_b, axis_e = _unit(rng), _unit(rng)

    def score(design: Design) -> float:
        own = _lengths(design)
        if "e" in own:
            fit = math.exp(-((own["e"] - 0.42) ** 2) / 0.01)
            return 0.3 + 0.7 * fit * _alignment(design, {"e": axis_e})
        return 0.5 * _alignment(design, {"b": axis_b})

    return score


def interaction() -> Callable[[Design], float]:
    rng = np.random.default_rng(404)
    ceilings = [1.0, 0.9, 0.8, 0.7]
    per_tree = [
        (
            {name: float(rng.uniform(0.15, 0.45)) for name in "abcd"},
            {name: float(rng.uniform(0.03, 0.07)) for name in "abcd"},
            {name: _unit(rng) for name in "bcd"},
        )
        for _ in ARMS4_STRUCTURES
    ]

    def score(design: Design) -> float:
        lengths, radii, axes = per_tree[design.structure_index]
        misfit = sum((link.length - lengths[link.name]) ** 2 for link in design.links) / 0.04
        misfit += sum((link.radius - radii[link.name]) ** 2 for link in design.links) / 0.001
        fit = math.exp(-misfit)
        return ceilings[design.structure_index] * fit * (0.3 + 0.7 * _alignment(design, axes))

    return score


# -- additive families: a wrong tree keeps improving with its specs (issue 26) ------
#
# Each score is ``w * tree_value[tree] + (1 - w) * spec_term``: a study that settles
# on a wrong tree still sees its score rise as its specs improve, which is the trap a
# model falls into when it believes unseen trees behave like the ones it has seen.
# Which tree is best is drawn from each objective's own generator, so it is rarely
# among a study's first designs.


def _tree_values(
    rng: np.random.Generator, count: int, worst: float, runner_up: float, best: int | None = None
) -> np.ndarray:
    """One best tree at 1 (``best``, else drawn), the others uniform in [worst, runner_up]."""
    values = rng.uniform(worst, runner_up, size=count)
    values[rng.integers(count) if best is None else best] = 1.0
    return values


def additive_trap() -> Callable[[Design], float]:
    """8 trees; the tree counts 45%, lengths and axes every tree has count 55%. The
    best tree is the smallest (a-b-c), the one with the fewest specs to search."""
    rng = np.random.default_rng(505)
    tree_values = _tree_values(rng, len(LIMBS5_STRUCTURES), 0.0, 0.35, best=0)
    axes = {name: _unit(rng) for name in "bc"}
    lengths = {"a": 0.32, "b": 0.21, "c": 0.40}

    def score(design: Design) -> float:
        own = _lengths(design)
        fit = math.exp(-sum((own[k] - lengths[k]) ** 2 for k in lengths) / 0.03)
        spec = fit * (0.4 + 0.6 * _alignment(design, axes))
        return 0.45 * tree_values[design.structure_index] + 0.55 * spec

    return score


def shifted_optima() -> Callable[[Design], float]:
    """8 trees, each with its own optimal lengths and axes near a shared one: what was
    learned on one tree is roughly, not exactly, right on another. The best tree is the
    star a-(b, c, d)."""
    rng = np.random.default_rng(606)
    tree_values = _tree_values(rng, len(LIMBS5_STRUCTURES), 0.1, 0.5, best=4)
    base_lengths = {name: float(rng.uniform(0.2, 0.4)) for name in "abcde"}
    base_axes = {name: _unit(rng) for name in "bcde"}
    per_tree = []
    for _ in LIMBS5_STRUCTURES:
        lengths = {k: v + float(rng.normal(0, 0.05)) for k, v in base_lengths.items()}
        axes = {}
        for name, axis in base_axes.items():
            tilted = axis + 0.4 * _unit(rng)
            axes[name] = tilted / np.linalg.norm(tilted)
        per_tree.append((lengths, axes))

    def score(design: Design) -> float:
        lengths, axes = per_tree[design.structure_index]
        own = _lengths(design)
        fit = math.exp(-sum((own[k] - lengths[k]) ** 2 for k in own) / (0.02 * len(own)))
        spec = fit * (0.3 + 0.7 * _alignment(design, axes))
        return 0.4 * tree_values[design.structure_index] + 0.6 * spec

    return score


# -- spec-dominated families: one sample per tree misranks the trees (issue 37) ------
#
# Each tree has its own ceiling, optimum and width, and the specs decide far more than
# the tree: the best tree's optimum is narrow, so a random design of it scores poorly,
# and a mediocre decoy tree has a broad plateau, so its random design looks best. A
# search that ranks the trees by one design each commits to the decoy.


@dataclass(frozen=True)
class SpecDominated:
    """A spec-dominated objective (``spec_dominated``): a score of a design, and each
    tree's ceiling (the most any design of it scores), so a test can ask a study's best
    to beat every other tree's."""

    score: Callable[[Design], float]
    ceilings: tuple[float, ...]
    best: int
    """The tree of ceiling 1."""

    def __call__(self, design: Design) -> float:
        return self.score(design)

    def others_ceiling(self) -> float:
        """The most a design of any tree but the best scores."""
        return max(c for tree, c in enumerate(self.ceilings) if tree != self.best)


def spec_dominated(
    layout_seed: int,
    narrow: float,
    broad: float,
    shift: float,
    others: tuple[float, float] | None = None,
    decoy: tuple[float, float] = (0.35, 0.45),
) -> SpecDominated:
    """8 trees; the score is ``ceiling[tree] * fit * (0.3 + 0.7 * alignment)``, where
    ``fit`` is a Gaussian bump of the links' lengths (root-mean-square distance to the
    tree's optimum over its width). The best tree (ceiling 1) has width ``narrow``; a
    decoy (ceiling in ``decoy``) has width ``broad``; the others ceilings 0.3 to 0.75
    and widths in ``others`` (by default a quarter to 0.6 of the way from narrow to
    broad). Every tree's optimal lengths and axes lie near shared ones
    (normal offsets of ``shift`` in length, tilts of ``shift`` in the axes), so what a
    study learns of one tree is roughly right on another. The best and decoy trees are
    drawn from ``layout_seed``."""
    rng = np.random.default_rng([909, layout_seed])
    count = len(LIMBS5_STRUCTURES)
    best, decoy_tree = (int(i) for i in rng.choice(count, size=2, replace=False))
    ceilings = rng.uniform(0.3, 0.75, size=count)
    if others is None:
        others = (narrow + 0.25 * (broad - narrow), narrow + 0.6 * (broad - narrow))
    widths = rng.uniform(*others, count)
    ceilings[best], widths[best] = 1.0, narrow
    ceilings[decoy_tree], widths[decoy_tree] = float(rng.uniform(*decoy)), broad
    base_lengths = {name: float(rng.uniform(0.2, 0.4)) for name in "abcde"}
    base_axes = {name: _unit(rng) for name in "bcde"}
    per_tree = []
    for _ in LIMBS5_STRUCTURES:
        lengths = {
            k: float(np.clip(v + rng.normal(0, shift), 0.12, 0.48)) for k, v in base_lengths.items()
        }
        axes = {}
        for name, axis in base_axes.items():
            tilted = axis + shift * 4.0 * _unit(rng)
            axes[name] = tilted / np.linalg.norm(tilted)
        per_tree.append((lengths, axes))

    def score(design: Design) -> float:
        tree = design.structure_index
        lengths, axes = per_tree[tree]
        own = _lengths(design)
        misfit = sum((own[k] - lengths[k]) ** 2 for k in own) / len(own)
        fit = math.exp(-misfit / (2.0 * widths[tree] ** 2))
        return float(ceilings[tree]) * fit * (0.3 + 0.7 * _alignment(design, axes))

    return SpecDominated(score, tuple(float(c) for c in ceilings), best)


SPEC_DOMINATED: dict[str, tuple[Any, ...]] = {
    "spec-dominated-1": (1, 0.05, 0.35, 0.03),
    "spec-dominated-2": (2, 0.07, 0.30, 0.05),
    "spec-dominated-3": (3, 0.04, 0.40, 0.02),
    "spec-dominated-4": (4, 0.06, 0.30, 0.08),
    # as issue 37's trap: every other tree narrow too, the decoy's plateau low
    "spec-dominated-5": (5, 0.06, 0.35, 0.03, (0.07, 0.10), (0.15, 0.25)),
    "spec-dominated-6": (6, 0.05, 0.30, 0.05, (0.06, 0.12), (0.15, 0.25)),
}
"""Layout seed, narrow width, broad width, shift (and the other trees' widths, the
decoy's ceiling) of each spec-dominated objective."""


def all_trees_space(names: str, radius: bool) -> dict[str, Any]:
    link: dict[str, Any] = {"length": {"low": 0.1, "high": 0.5}, "radius": 0.04, "mass": 1.0}
    if radius:
        link["radius"] = {"low": 0.02, "high": 0.08}
    return {
        "type": "design",
        "parts": {"link": link},
        "instances": [{"name": name, "part": "link"} for name in names],
        "structures": "all",
    }


def _edge_sets(space: dict[str, Any]) -> list[set[tuple[str, str]]]:
    space = {**space, "max_structures": 1000}
    return [set(edges) for edges in DesignSpace.model_validate(space).tree_structures()]


def needle_16() -> Callable[[Design], float]:
    """Every tree of 4 links (16): one tree far better than the rest, unrelated to how
    alike the trees are; lengths, radii and axes add half the score on any tree."""
    rng = np.random.default_rng(707)
    tree_values = _tree_values(rng, 16, 0.0, 0.4)
    radii = {name: float(rng.uniform(0.03, 0.07)) for name in "abcd"}
    lengths = {name: float(rng.uniform(0.15, 0.45)) for name in "abcd"}
    axes = {name: _unit(rng) for name in "bcd"}

    def score(design: Design) -> float:
        misfit = sum((link.length - lengths[link.name]) ** 2 for link in design.links) / 0.05
        misfit += sum((link.radius - radii[link.name]) ** 2 for link in design.links) / 0.002
        spec = math.exp(-misfit) * (0.3 + 0.7 * _alignment(design, axes))
        return 0.5 * tree_values[design.structure_index] + 0.5 * spec

    return score


def _depth(edges: set[tuple[str, str]], root: str) -> int:
    children: dict[str, list[str]] = {}
    for parent, child in edges:
        children.setdefault(parent, []).append(child)

    def down(node: str) -> int:
        return 1 + max((down(c) for c in children.get(node, [])), default=0)

    return down(root)


def tree_shape_64() -> tuple[Callable[[Design], float], list[list[tuple[str, str]]]]:
    """64 of the 125 trees of 5 links: the tree's value follows its shape (depth,
    leaves, the root's degree), so alike trees score alike but the best shape is one
    tree of few; lengths every tree has and the axes add 55%."""
    rng = np.random.default_rng(808)
    edge_sets = _edge_sets(all_trees_space("abcde", radius=False))
    depth_target, leaves_target = 4, 2
    axes = {name: _unit(rng) for name in "bcde"}
    lengths = {name: float(rng.uniform(0.15, 0.45)) for name in "abcde"}
    values = []
    for edges in edge_sets:
        parents = {p for p, _ in edges}
        leaves = len({c for _, c in edges} - parents)
        root_degree = sum(1 for p, _ in edges if p == "a")
        value = math.exp(-((_depth(edges, "a") - 1 - depth_target) ** 2) / 2.0)
        value *= math.exp(-((leaves - leaves_target) ** 2) / 2.0) * (0.8 + 0.2 * (root_degree == 1))
        values.append(value)
    order = rng.permutation(len(edge_sets))
    best = int(np.argmax(values))
    chosen = [best, *[int(i) for i in order if int(i) != best][:63]]
    chosen.sort()
    tree_values = np.array([values[i] for i in chosen])
    tree_values /= tree_values.max()

    def score(design: Design) -> float:
        own = _lengths(design)
        fit = math.exp(-sum((own[k] - lengths[k]) ** 2 for k in own) / 0.1)
        spec = fit * (0.3 + 0.7 * _alignment(design, axes))
        return 0.45 * tree_values[design.structure_index] + 0.55 * spec

    return score, [sorted(edge_sets[i], key=lambda e: (e[0], e[1])) for i in chosen]


def tree_shape_space(structures: list[list[tuple[str, str]]]) -> dict[str, Any]:
    space = all_trees_space("abcde", radius=False)
    space["structures"] = [[list(edge) for edge in edges] for edges in structures]
    return space


@dataclass(frozen=True)
class Objective:
    name: str
    space: dict[str, Any]
    score: Callable[[Design], float]


OBJECTIVES = {
    "tree-similarity": Objective("tree-similarity", limbs5_space(), tree_similarity()),
    "specs-only": Objective("specs-only", limbs5_space(), specs_only()),
    "unused-specs": Objective("unused-specs", limbs5_space(), unused_specs()),
    "interaction": Objective("interaction", arms4_space(), interaction()),
    "additive-trap": Objective("additive-trap", limbs5_space(), additive_trap()),
    "shifted-optima": Objective("shifted-optima", limbs5_space(), shifted_optima()),
    "needle-16": Objective("needle-16", all_trees_space("abcd", radius=True), needle_16()),
}
_SHAPE_SCORE, _SHAPE_TREES = tree_shape_64()
OBJECTIVES["tree-shape-64"] = Objective(
    "tree-shape-64", tree_shape_space(_SHAPE_TREES), _SHAPE_SCORE
)
for _name, _layout in SPEC_DOMINATED.items():
    OBJECTIVES[_name] = Objective(_name, limbs5_space(), spec_dominated(*_layout))
EIGHT_TREES = {
    name
    for name, o in OBJECTIVES.items()
    if o.space is not None and o.space.get("structures") == LIMBS5_STRUCTURES
}
"""The objectives on the 8-tree, 13-spec space (issue 26's latency goal)."""
