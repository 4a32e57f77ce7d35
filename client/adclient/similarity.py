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

What it costs: a pair of trees of n and m links computes at most one tree distance and
one forest distance per pair of their nodes, each a loop over the two nodes' children
and, for the forests, a Hungarian matching of the children (cubic in their count).
:func:`similarity_steps` bounds the steps of a whole matrix from the trees' sizes and
branching before any is computed, so a server can refuse a space whose matrix would
cost too much (``AD_CREATE_SIMILARITY_STEPS``). Subtrees are numbered once and the
distances memoised on those numbers (a bounded memo shared by the matrix's pairs), so
structures that share subtrees cost less than the bound.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

Tree = tuple[tuple[str, str], tuple["Tree", ...]]
"""Canonical rooted tree: ((instance, part type), children sorted)."""

Label = tuple[str, str]

_INFINITY = 1e18
MEMO_ENTRIES = 1 << 19
"""Memoised distances kept at most (each memo), about 40 MB; past it the memo is emptied
between two pairs of trees, never within one (so :func:`similarity_steps` bounds it)."""


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


def _relabel(a: Label, b: Label) -> float:
    if a == b:
        return 0.0
    if a[1] == b[1]:
        return 0.5
    return 1.0


class _Subtrees:
    """Every distinct subtree of the trees added, numbered, with its label, its children's
    numbers and its size: the distances are memoised on pairs of numbers (hashing a
    nested tuple costs its whole size at every lookup)."""

    def __init__(self) -> None:
        self._numbers: dict[tuple[Label, tuple[int, ...]], int] = {}
        self.label: list[Label] = []
        self.children: list[tuple[int, ...]] = []
        self.size: list[int] = []

    def add(self, tree: Tree) -> int:
        label, subtrees = tree
        children = tuple(self.add(child) for child in subtrees)
        key = (label, children)
        number = self._numbers.get(key)
        if number is None:
            number = self._numbers[key] = len(self.label)
            self.label.append(label)
            self.children.append(children)
            self.size.append(1 + sum(self.size[child] for child in children))
        return number


class _EditDistance:
    """The constrained edit distance between numbered subtrees (``_Subtrees``), memoised;
    ``steps`` counts the work done (what :func:`similarity_steps` bounds)."""

    def __init__(self, subtrees: _Subtrees) -> None:
        self.subtrees = subtrees
        self.steps = 0
        self._trees: dict[tuple[int, int], float] = {}
        self._forests: dict[tuple[int, int], float] = {}

    def between(self, a: int, b: int) -> float:
        """The distance between two whole trees (the memo is emptied first if full)."""
        if len(self._trees) > MEMO_ENTRIES or len(self._forests) > MEMO_ENTRIES:
            self._trees.clear()
            self._forests.clear()
        return self.tree(a, b)

    def tree(self, a: int, b: int) -> float:
        key = (a, b)
        found = self._trees.get(key)
        if found is not None:
            return found
        size, children = self.subtrees.size, self.subtrees.children
        size_a, size_b = size[a], size[b]
        best = self.forest(a, b) + _relabel(self.subtrees.label[a], self.subtrees.label[b])
        # a maps into one subtree of b; b's root and its other subtrees are inserted
        for child in children[b]:
            best = min(best, size_b + self.tree(a, child) - size[child])
        # b maps into one subtree of a; a's root and its other subtrees are deleted
        for child in children[a]:
            best = min(best, size_a + self.tree(child, b) - size[child])
        self.steps += 2 + len(children[a]) + len(children[b])
        self._trees[key] = best
        return best

    def forest(self, a: int, b: int) -> float:
        """The distance between a's children and b's children (two forests)."""
        size, children = self.subtrees.size, self.subtrees.children
        forest_a, forest_b = children[a], children[b]
        if not forest_a:
            return float(size[b] - 1)
        if not forest_b:
            return float(size[a] - 1)
        key = (a, b)
        found = self._forests.get(key)
        if found is not None:
            return found
        size_a, size_b = size[a] - 1, size[b] - 1
        best = size_a + size_b + self._matching(forest_a, forest_b)
        # forest a maps into the children of one root of b (that root is inserted)
        for tree in forest_b:
            best = min(best, size_b + self.forest(a, tree) - (size[tree] - 1))
        for tree in forest_a:
            best = min(best, size_a + self.forest(tree, b) - (size[tree] - 1))
        self.steps += len(forest_a) + len(forest_b)
        self._forests[key] = best
        return best

    def _matching(self, a: tuple[int, ...], b: tuple[int, ...]) -> float:
        """The least of sum(d(x, y) - |x| - |y|) over matchings of trees of a to trees of
        b: what matching saves over deleting a and inserting b. Each such term is at
        most 0 (a distance is at most both sizes), so the best matching is a complete
        one of the smaller forest."""
        size = self.subtrees.size
        if len(a) > len(b):
            a, b = b, a
            rows = [[self.tree(y, x) - size[x] - size[y] for y in b] for x in a]
        else:
            rows = [[self.tree(x, y) - size[x] - size[y] for y in b] for x in a]
        self.steps += len(a) * len(b)
        if len(a) == 1:
            return min(rows[0])
        cost, iterations = _assignment(rows)
        self.steps += iterations * (len(b) + 1)
        return cost


def _assignment(cost: list[list[float]]) -> tuple[float, int]:
    """Minimum total cost of assigning every row to its own column (rows <= columns;
    the Hungarian method with potentials, O(rows^2 columns)), and the inner loops it ran."""
    rows, columns = len(cost), len(cost[0])
    u = [0.0] * (rows + 1)
    v = [0.0] * (columns + 1)
    match = [0] * (columns + 1)  # match[column] = row, 1-based, 0 = free
    way = [0] * (columns + 1)
    iterations = 0
    for row in range(1, rows + 1):
        match[0] = row
        column0 = 0
        minimum = [_INFINITY * 10] * (columns + 1)
        used = [False] * (columns + 1)
        while True:
            iterations += 1
            used[column0] = True
            row0 = match[column0]
            costs, offset = cost[row0 - 1], u[row0]
            delta = _INFINITY * 10
            column1 = 0
            for column in range(1, columns + 1):
                if not used[column]:
                    reduced = costs[column - 1] - offset - v[column]
                    if reduced < minimum[column]:
                        minimum[column] = reduced
                        way[column] = column0
                    if minimum[column] < delta:
                        delta = minimum[column]
                        column1 = column
            for column in range(columns + 1):
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
    total = sum(
        cost[match[column] - 1][column - 1] for column in range(1, columns + 1) if match[column]
    )
    return total, iterations


def _shape(edges: Sequence[tuple[str, str]]) -> tuple[int, int, int]:
    """A tree's node count, edge count and sum of squared child counts."""
    child_count: dict[str, int] = {}
    for parent, _ in edges:
        child_count[parent] = child_count.get(parent, 0) + 1
    return len(edges) + 1, len(edges), sum(count * count for count in child_count.values())


def similarity_steps(structures: Sequence[Sequence[tuple[str, str]]]) -> int:
    """An upper bound on the steps :func:`similarity_matrix` takes over these structures
    (those :func:`similarity_matrix_steps` counts), in time linear in their count.

    Per pair of nodes of two trees, with da and db children: a tree entry of
    2 + da + db steps, and a forest entry of da + db, da db costs and the Hungarian
    method's at most r (r + 1) / 2 loops of m + 1 (r and m the smaller and larger of da
    and db), so at most 2 + 2.5 (da + db) + 2 da db + (da^2 db + da db^2) / 4 in all.
    Summed over the node pairs, that is a sum of products of each tree's node count,
    edge count (the sum of its d) and sum of d squared, and summed over the pairs of
    trees, products of those sums. What the memo saves is not counted."""
    shapes = [_shape(edges) for edges in structures]
    n = [shape[0] for shape in shapes]
    e = [shape[1] for shape in shapes]
    q = [shape[2] for shape in shapes]

    def cross(x: list[int], y: list[int]) -> int:
        """The sum over pairs i < j of x_i y_j + x_j y_i."""
        return sum(x) * sum(y) - sum(a * b for a, b in zip(x, y, strict=True))

    def square(x: list[int]) -> int:
        """The sum over pairs i < j of x_i x_j."""
        return (sum(x) ** 2 - sum(a * a for a in x)) // 2

    quadruple = 8 * square(n) + 10 * cross(e, n) + 8 * square(e) + cross(q, e)
    return -(-quadruple // 4)  # the bound times 4 is an integer


def tree_edit_distance(
    a: Sequence[tuple[str, str]],
    b: Sequence[tuple[str, str]],
    part_of: Mapping[str, str] | None = None,
) -> float:
    """Constrained unordered edit distance between two rooted trees given as edges."""
    subtrees = _Subtrees()
    tree_a, tree_b = (
        subtrees.add(canonical_tree(a, part_of)),
        subtrees.add(canonical_tree(b, part_of)),
    )
    return _EditDistance(subtrees).between(tree_a, tree_b)


def structure_similarity(
    a: Sequence[tuple[str, str]],
    b: Sequence[tuple[str, str]],
    part_of: Mapping[str, str] | None = None,
) -> float:
    """Similarity in [0, 1] of two structures (edge lists); 1 iff they are the same tree.

    ``part_of`` maps instance names to part types (see the module docstring); without
    it every instance counts as its own part type.
    """
    return float(similarity_matrix([a, b], part_of)[0, 1])


def similarity_matrix_steps(
    structures: Sequence[Sequence[tuple[str, str]]],
    part_of: Mapping[str, str] | None = None,
) -> tuple[np.ndarray, int]:
    """:func:`similarity_matrix` and the steps it took (at most :func:`similarity_steps`)."""
    subtrees = _Subtrees()
    trees = [subtrees.add(canonical_tree(edges, part_of)) for edges in structures]
    distance = _EditDistance(subtrees)
    count = len(trees)
    matrix = np.ones((count, count), dtype=np.float64)
    for i in range(count):
        for j in range(i + 1, count):
            d = distance.between(trees[i], trees[j])
            total = subtrees.size[trees[i]] + subtrees.size[trees[j]]
            matrix[i, j] = matrix[j, i] = 1.0 - 2.0 * d / (total + d)
    return matrix, distance.steps


def similarity_matrix(
    structures: Sequence[Sequence[tuple[str, str]]],
    part_of: Mapping[str, str] | None = None,
) -> np.ndarray:
    """Symmetric S x S matrix of structure similarities, ones on the diagonal."""
    return similarity_matrix_steps(structures, part_of)[0]
