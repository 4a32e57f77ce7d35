"""The structure similarity's cost is bounded before it is computed (issue 58): the steps
``similarity_matrix`` takes never exceed ``similarity_steps``, whatever the trees'
shapes, and its values are the constrained edit distance's, computed here again by
the textbook formulation (a square assignment of children with a dummy row or column
for each deletion and insertion, no memo) for small trees."""

from __future__ import annotations

import itertools
import random
from collections.abc import Sequence

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from adclient.similarity import (
    Tree,
    canonical_tree,
    similarity_matrix,
    similarity_matrix_steps,
    similarity_steps,
    structure_similarity,
    tree_edit_distance,
)
from adclient.trees import all_trees
from tests.client.design_strategies import trees

NAMES = [f"n{i}" for i in range(32)]
PART_OF = {name: "link" if int(name[1:]) % 3 else "limb" for name in NAMES}


def shaped_tree(rng: random.Random, links: int, shape: str) -> list[tuple[str, str]]:
    """A tree of ``links`` links over shuffled names: a path, a star, a broom (every
    other link on the root) or a random recursive tree."""
    names = rng.sample(NAMES, links)
    edges = []
    for index in range(1, links):
        parent = {
            "path": index - 1,
            "star": 0,
            "broom": 0 if index % 2 else max(0, index - 2),
            "random": rng.randrange(index),
        }[shape]
        edges.append((names[parent], names[index]))
    return edges


def reference_distance(a: Tree, b: Tree) -> float:
    """Zhang's constrained edit distance, written as the paper writes it."""

    def size(tree: Tree) -> int:
        return 1 + sum(size(child) for child in tree[1])

    def forest_size(forest: Sequence[Tree]) -> int:
        return sum(size(tree) for tree in forest)

    def relabel(x: tuple[str, str], y: tuple[str, str]) -> float:
        return 0.0 if x == y else 0.5 if x[1] == y[1] else 1.0

    def tree_distance(a: Tree, b: Tree) -> float:
        best = forest_distance(a[1], b[1]) + relabel(a[0], b[0])
        for child in b[1]:
            best = min(best, size(b) + tree_distance(a, child) - size(child))
        for child in a[1]:
            best = min(best, size(a) + tree_distance(child, b) - size(child))
        return best

    def forest_distance(a: Sequence[Tree], b: Sequence[Tree]) -> float:
        if not a or not b:
            return float(forest_size(a) + forest_size(b))
        best = matching(a, b)
        for tree in b:
            best = min(best, forest_size(b) + forest_distance(a, tree[1]) - forest_size(tree[1]))
        for tree in a:
            best = min(best, forest_size(a) + forest_distance(tree[1], b) - forest_size(tree[1]))
        return best

    def matching(a: Sequence[Tree], b: Sequence[Tree]) -> float:
        """Every assignment of a + (deletions) to b + (insertions), tried."""
        rows = [*a, *[None] * len(b)]
        best = float("inf")
        for columns in itertools.permutations([*b, *[None] * len(a)]):
            total, allowed = 0.0, True
            for number, (row, column) in enumerate(zip(rows, columns, strict=True)):
                if row is not None and column is not None:
                    total += tree_distance(row, column)
                elif row is not None:
                    total += size(row)
                elif column is not None:
                    total += size(column)
                elif number < len(a):
                    allowed = False
            if allowed:
                best = min(best, total)
        return best

    return tree_distance(a, b)


@settings(max_examples=150, deadline=None)
@given(st.data())
def test_the_distance_is_the_textbook_constrained_edit_distance(data: st.DataObject) -> None:
    def tree() -> list[tuple[str, str]]:
        size = data.draw(st.integers(2, 5))  # the reference tries every assignment
        return data.draw(trees(["a", "b", "c", "d", "e"][:size]))

    a, b = tree(), tree()
    part_of = data.draw(st.none() | st.just({n: "x" if n in "abc" else "y" for n in "abcde"}))
    expected = reference_distance(canonical_tree(a, part_of), canonical_tree(b, part_of))
    assert tree_edit_distance(a, b, part_of) == expected


@pytest.mark.parametrize("shape", ["path", "star", "broom", "random"])
@pytest.mark.parametrize("links", [2, 5, 12, 32])
def test_a_matrix_takes_at_most_the_steps_bounded_before_it(shape: str, links: int) -> None:
    rng = random.Random(f"{shape} {links}")
    structures = [shaped_tree(rng, links, rng.choice([shape, "random"])) for _ in range(12)]
    matrix, steps = similarity_matrix_steps(structures, PART_OF)
    assert 0 < steps <= similarity_steps(structures)
    assert (matrix == similarity_matrix(structures, PART_OF)).all()


def test_the_bound_is_the_sum_of_each_pairs_bound() -> None:
    rng = random.Random(5)
    structures = [shaped_tree(rng, rng.randint(2, 32), "random") for _ in range(9)]
    pairs = sum(similarity_steps([a, b]) for a, b in itertools.combinations(structures, 2))
    # each pair's bound is rounded up on its own
    assert pairs - 36 <= similarity_steps(structures) <= pairs


def test_shared_subtrees_cost_less_than_the_bound() -> None:
    structures = list(all_trees(["a", "b", "c", "d", "e"]))  # 125 trees sharing subtrees
    _, steps = similarity_matrix_steps(structures)
    assert steps < similarity_steps(structures) / 2


def test_a_pair_of_trees_is_its_matrix_entry() -> None:
    rng = random.Random(9)
    a, b = shaped_tree(rng, 9, "random"), shaped_tree(rng, 7, "broom")
    assert structure_similarity(a, b, PART_OF) == similarity_matrix([a, b], PART_OF)[0, 1]
    assert structure_similarity(a, a, PART_OF) == 1.0
