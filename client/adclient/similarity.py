"""Structure similarity between candidate trees, in [0, 1] (1 = the same tree).

The measure is a normalised *constrained unordered tree edit distance* (Zhang, 1996,
"A constrained edit distance between unordered labeled trees", Algorithmica 15)
between the two rooted trees, with unit costs for deleting or inserting a link and
for turning one instance into an instance of another part type, half that between
two instances of the same part type, and nothing for keeping an instance. Why this
one:

- *Rooted*: the root is the base link, and children sit at their parent's far end,
  so re-rooting a tree changes the robot; the root must count.
- *Unordered*: a link's children all hang from the same joint site, so the order in
  which a structure lists them means nothing; an ordered edit distance would call
  two listings of one robot different.
- *Constrained* (disjoint subtrees map to disjoint subtrees): the unrestricted
  unordered edit distance is NP-hard (Zhang, Statman and Shasha, 1992); the
  constrained one is polynomial (a min-cost bipartite matching of children per
  node pair), is still a metric, and on trees of a handful of links equals the
  unrestricted one in nearly every case that matters here (moving a subtree).
- *Labels*: the instance names make ``g = 1`` exactly for identical trees, so two
  different structures never share the top similarity level and the fusion keeps
  them apart; the part type makes swapping two interchangeable links (same part
  type) cost half as much as swapping a link for a different kind of part, so
  structures that are the same shape rank as more alike.
- *Normalisation*: ``2 d / (|T1| + |T2| + d)`` (Li and Chen, 2011), which maps the
  distance into [0, 1] and stays a metric; the similarity is one minus it.

Subtree distances are memoised on canonical forms, so a whole similarity matrix
over many structures that share subtrees costs little.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from functools import lru_cache

import numpy as np

Tree = tuple[tuple[str, str], tuple["Tree", ...]]
"""Canonical rooted tree: ((instance, part type), children sorted)."""

_INFINITY = 1e18


def canonical_tree(edges: Sequence[tuple[str, str]], part_of: Mapping[str, str] | None) -> Tree:
    """The rooted tree of an edge list, children sorted, so equal trees compare equal."""
    children: dict[str, list[str]] = {}
    child_set: set[str] = set()
    nodes: list[str] = []
    for parent, child in edges:
        children.setdefault(parent, []).append(child)
        child_set.add(child)
        for name in (parent, child):
            if name not in nodes:
                nodes.append(name)
    roots = [name for name in nodes if name not in child_set]
    if len(roots) != 1 or len(nodes) != len(edges) + 1:
        raise ValueError(f"edges {list(edges)} do not form one rooted tree")

    def build(name: str) -> Tree:
        label = (name, part_of.get(name, name) if part_of is not None else name)
        return (label, tuple(sorted(build(child) for child in children.get(name, []))))

    return build(roots[0])


@lru_cache(maxsize=1 << 16)
def _size(tree: Tree) -> int:
    return 1 + sum(_size(child) for child in tree[1])


def _forest_size(forest: tuple[Tree, ...]) -> int:
    return sum(_size(tree) for tree in forest)


def _relabel(a: tuple[str, str], b: tuple[str, str]) -> float:
    if a == b:
        return 0.0
    if a[1] == b[1]:
        return 0.5
    return 1.0


@lru_cache(maxsize=1 << 18)
def _tree_distance(a: Tree, b: Tree) -> float:
    size_a, size_b = _size(a), _size(b)
    best = _forest_distance(a[1], b[1]) + _relabel(a[0], b[0])
    # a maps into one subtree of b; b's root and its other subtrees are inserted
    for child in b[1]:
        best = min(best, size_b + _tree_distance(a, child) - _size(child))
    # b maps into one subtree of a; a's root and its other subtrees are deleted
    for child in a[1]:
        best = min(best, size_a + _tree_distance(child, b) - _size(child))
    return best


@lru_cache(maxsize=1 << 18)
def _forest_distance(a: tuple[Tree, ...], b: tuple[Tree, ...]) -> float:
    if not a:
        return float(_forest_size(b))
    if not b:
        return float(_forest_size(a))
    size_a, size_b = _forest_size(a), _forest_size(b)
    best = _matching_cost(a, b)
    # forest a maps into the children of one root of b (that root is inserted)
    for tree in b:
        best = min(best, size_b + _forest_distance(a, tree[1]) - _forest_size(tree[1]))
    for tree in a:
        best = min(best, size_a + _forest_distance(tree[1], b) - _forest_size(tree[1]))
    return best


def _matching_cost(a: tuple[Tree, ...], b: tuple[Tree, ...]) -> float:
    """Min-cost matching of trees of a to trees of b, the unmatched deleted/inserted."""
    na, nb = len(a), len(b)
    n = na + nb
    cost = [[0.0] * n for _ in range(n)]
    for s in range(n):
        for t in range(n):
            if s < na and t < nb:
                cost[s][t] = _tree_distance(a[s], b[t])
            elif s < na:
                cost[s][t] = float(_size(a[s])) if t - nb == s else _INFINITY
            elif t < nb:
                cost[s][t] = float(_size(b[t])) if s - na == t else _INFINITY
    return _assignment(cost)


def _assignment(cost: list[list[float]]) -> float:
    """Minimum total cost of a perfect assignment (Hungarian method, O(n^3))."""
    n = len(cost)
    u = [0.0] * (n + 1)
    v = [0.0] * (n + 1)
    match = [0] * (n + 1)  # match[column] = row, 1-based, 0 = free
    way = [0] * (n + 1)
    for row in range(1, n + 1):
        match[0] = row
        column0 = 0
        minimum = [_INFINITY * 10] * (n + 1)
        used = [False] * (n + 1)
        while True:
            used[column0] = True
            row0 = match[column0]
            delta = _INFINITY * 10
            column1 = 0
            for column in range(1, n + 1):
                if not used[column]:
                    reduced = cost[row0 - 1][column - 1] - u[row0] - v[column]
                    if reduced < minimum[column]:
                        minimum[column] = reduced
                        way[column] = column0
                    if minimum[column] < delta:
                        delta = minimum[column]
                        column1 = column
            for column in range(n + 1):
                if used[column]:
                    u[match[column]] += delta
                    v[column] -= delta
                else:
                    minimum[column] -= delta
            column0 = column1
            if match[column0] == 0:
                break
        while column0:
            column1 = way[column0]
            match[column0] = match[column1]
            column0 = column1
    return sum(cost[match[column] - 1][column - 1] for column in range(1, n + 1))


def tree_edit_distance(
    a: Sequence[tuple[str, str]],
    b: Sequence[tuple[str, str]],
    part_of: Mapping[str, str] | None = None,
) -> float:
    """Constrained unordered edit distance between two rooted trees given as edges."""
    return _tree_distance(canonical_tree(a, part_of), canonical_tree(b, part_of))


def structure_similarity(
    a: Sequence[tuple[str, str]],
    b: Sequence[tuple[str, str]],
    part_of: Mapping[str, str] | None = None,
) -> float:
    """Similarity in [0, 1] of two structures (edge lists); 1 iff they are the same tree.

    ``part_of`` maps instance names to part types (see the module docstring); without
    it every instance counts as its own part type.
    """
    tree_a, tree_b = canonical_tree(a, part_of), canonical_tree(b, part_of)
    distance = _tree_distance(tree_a, tree_b)
    total = _size(tree_a) + _size(tree_b)
    return 1.0 - 2.0 * distance / (total + distance)


def similarity_matrix(
    structures: Sequence[Sequence[tuple[str, str]]],
    part_of: Mapping[str, str] | None = None,
) -> np.ndarray:
    """Symmetric S x S matrix of structure similarities, ones on the diagonal."""
    trees = [canonical_tree(edges, part_of) for edges in structures]
    count = len(trees)
    matrix = np.ones((count, count), dtype=np.float64)
    for i in range(count):
        for j in range(i + 1, count):
            distance = _tree_distance(trees[i], trees[j])
            total = _size(trees[i]) + _size(trees[j])
            matrix[i, j] = matrix[j, i] = 1.0 - 2.0 * distance / (total + distance)
    return matrix
