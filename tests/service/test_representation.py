"""Fusion (OSQP against the exact oracle, the oracle against an independent QP) and the
representation built for each example space."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import osqp
import pytest
import scipy.sparse as sp
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from scipy.spatial.distance import pdist, squareform

from adclient.decode import decode, mixed_bounds, spec_layout
from adclient.design import DesignSpace
from adclient.designs import Representation
from adclient.encode import encode
from adclient.schemas import StudyCreate
from adclient.urdf import design_to_urdf
from adservice.fusion import (
    GAP_TOLERANCE,
    VIOLATION_TOLERANCE,
    check_pairs,
    exact_pairs,
    fuse,
    fuse_distances,
    fusion_check,
    pair_problem,
)
from adservice.representation import (
    STRUCTURE_DISTANCE_FLOOR,
    build_representation,
    classical_mds,
    search_structure,
    structure_distances,
    structure_embedding,
)

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


@st.composite
def fusion_problems(draw: st.DrawFn, max_points: int = 24) -> tuple[np.ndarray, np.ndarray, float]:
    """Random points (so D is a real distance matrix) in random structure groups, with a
    structure similarity table of few distinct levels, so G has many ties."""
    count = draw(st.integers(3, max_points))
    dim = draw(st.integers(1, 4))
    points = draw(
        hnp.arrays(np.float64, (count, dim), elements=st.floats(0, 1, allow_subnormal=False))
    )
    groups = draw(st.integers(1, 5))
    labels = np.array(draw(st.lists(st.integers(0, groups - 1), min_size=count, max_size=count)))
    levels = draw(
        st.lists(
            st.sampled_from([0.0, 0.25, 0.5, 0.75]),
            min_size=groups * groups,
            max_size=groups * groups,
        )
    )
    table = np.array(levels).reshape(groups, groups)
    table = np.triu(table, 1) + np.triu(table, 1).T + np.eye(groups)
    D = np.sqrt(((points[:, None, :] - points[None, :, :]) ** 2).sum(-1))
    G = table[np.ix_(labels, labels)]
    margin = draw(st.sampled_from([0.0, 0.0, 0.05, 0.3]))
    return D, G, margin


def all_pairs_qp(D: np.ndarray, G: np.ndarray, margin: float) -> np.ndarray:
    """The fusion QP written independently of both solvers under test: one constraint
    for every ordered pair of pairs in consecutive levels (dense), solved by OSQP at
    tight tolerances with polishing."""
    problem = pair_problem(D, G, margin)
    n = problem.d.size
    rows: list[int] = []
    cols: list[int] = []
    values: list[float] = []
    lower: list[float] = []
    for level in range(problem.n_levels - 1):
        near = np.flatnonzero(problem.level == level)
        far = np.flatnonzero(problem.level == level + 1)
        for k in far:
            for j in near:
                r = len(lower)
                rows += [r, r]
                cols += [int(k), int(j)]
                values += [1.0, -1.0]
                lower.append(margin)
    for pair in range(n):
        rows.append(len(lower))
        cols.append(pair)
        values.append(1.0)
        lower.append(0.0)
    A = sp.csc_matrix((values, (rows, cols)), shape=(len(lower), n))
    solver = osqp.OSQP()
    solver.setup(
        sp.eye(n, format="csc"),
        -problem.d,
        A,
        np.array(lower),
        np.full(len(lower), np.inf),
        eps_abs=1e-11,
        eps_rel=1e-11,
        max_iter=200_000,
        polishing=True,
        verbose=False,
    )
    return solver.solve(raise_error=False).x


@settings(max_examples=40, deadline=None)
@given(fusion_problems(max_points=12))
def test_exact_oracle_is_the_optimum(case: tuple[np.ndarray, np.ndarray, float]) -> None:
    D, G, margin = case
    problem = pair_problem(D, G, margin)
    exact = exact_pairs(problem)
    check = check_pairs(problem, exact)
    assert check.max_violation <= 1e-12
    independent = all_pairs_qp(D, G, margin)
    # no feasible point does better (the independent solve may be a hair infeasible)
    assert check.objective <= problem.objective(independent) + 1e-6 * max(1.0, check.objective)
    assert check_pairs(problem, independent).max_violation <= 1e-6


@settings(max_examples=40, deadline=None)
@given(fusion_problems())
def test_osqp_matches_the_oracle(case: tuple[np.ndarray, np.ndarray, float]) -> None:
    D, G, margin = case
    F, info = fuse(D, G, margin, "osqp")
    assert info.get("fusion_fallback") is None  # OSQP's own answer passed the check
    check = fusion_check(D, G, F, margin)
    assert check.relative_gap <= GAP_TOLERANCE
    assert check.max_violation <= VIOLATION_TOLERANCE
    assert np.allclose(F, F.T) and np.all(np.diag(F) == 0)
    exact = fuse_distances(D, G, margin, solver="exact")
    assert fusion_check(D, G, exact, margin).max_violation <= 1e-12
    assert np.abs(F - exact).max() <= 1e-3 * max(1.0, float(D.max()))


@settings(max_examples=20, deadline=None)
@given(fusion_problems())
def test_fused_order_follows_similarity(case: tuple[np.ndarray, np.ndarray, float]) -> None:
    D, G, margin = case
    F = fuse_distances(D, G, margin, solver="exact")
    upper = np.triu_indices(len(D), 1)
    f, g = F[upper], G[upper]
    for more, less in zip(np.unique(g)[1:][::-1], np.unique(g)[:-1][::-1], strict=True):
        assert f[g == less].min() >= f[g == more].max() + margin - 1e-12
    assert np.all(f >= 0)


def test_fuse_rejects_bad_input() -> None:
    D = np.array([[0.0, 1.0], [2.0, 0.0]])
    with pytest.raises(ValueError, match="symmetric"):
        fuse_distances(D, np.ones((2, 2)))
    with pytest.raises(ValueError, match="one shape"):
        fuse_distances(np.zeros((2, 2)), np.ones((3, 3)))
    with pytest.raises(ValueError, match="unknown fusion solver"):
        fuse(np.zeros((2, 2)), np.ones((2, 2)), 0.0, "cvx")  # type: ignore[arg-type]


def test_already_ordered_distances_are_kept() -> None:
    points = np.array([[0.0], [0.1], [5.0], [5.2]])
    D = np.abs(points - points.T)
    labels = np.array([0, 0, 1, 1])
    G = np.where(labels[:, None] == labels[None, :], 1.0, 0.2)
    assert np.allclose(fuse_distances(D, G), D, atol=1e-9)


def test_mds_recovers_euclidean_points() -> None:
    rng = np.random.default_rng(3)
    points = rng.random((30, 3))
    D = np.sqrt(((points[:, None] - points[None]) ** 2).sum(-1))
    coords, info = classical_mds(D, mass=0.999)
    assert info["embedding_dim"] == 3
    again = np.sqrt(((coords[:, None] - coords[None]) ** 2).sum(-1))
    assert np.allclose(again, D, atol=1e-9)


# -- the examples ---------------------------------------------------------------------


def example_space(name: str) -> DesignSpace:
    body = StudyCreate.model_validate(yaml.safe_load((EXAMPLES / f"{name}.yaml").read_text()))
    assert isinstance(body.space, DesignSpace)
    return body.space


@pytest.mark.parametrize(("name", "dim"), [("stand-up", 7), ("diagonal-gesture", 4)])
def test_single_structure_examples_are_identity(name: str, dim: int) -> None:
    representation = build_representation(example_space(name))
    assert representation.kind == "identity"
    assert representation.bounds == [[0.0] * dim, [1.0] * dim]
    assert len(representation.spec_names) == dim


@pytest.fixture(scope="module")
def multi() -> tuple[DesignSpace, Representation]:
    """The preprint's fused encoding of the multi-structure example."""
    space = example_space("multi-structure").model_copy(update={"encoding": "fused"})
    return space, build_representation(space)


def test_multi_structure_default_is_mixed_with_structures_placed_apart() -> None:
    space = example_space("multi-structure")
    representation = build_representation(space)
    assert representation.kind == "mixed"
    count = len(space.tree_structures())
    assert representation.bounds == mixed_bounds(count, len(representation.spec_names))
    coords = np.asarray(representation.structure_coords)
    assert coords.shape[0] == count
    distance = squareform(pdist(coords))
    largest = distance.max()
    off = distance[~np.eye(count, dtype=bool)]
    # every structure apart from every other (the one-hot limit needs it), none further
    # than the scaled largest (up to the negative eigenvalues MDS drops)
    assert off.min() >= 0.5 * STRUCTURE_DISTANCE_FLOOR * largest
    assert largest <= 1.0 + 1e-9
    # the fusion orders them: the chain of 4 is nearer the chain of 5 than the tripod is
    chain4, tripod, chain5 = 2, 1, 5
    assert distance[chain4, chain5] < distance[tripod, chain5]
    assert build_representation(space).structure_coords == representation.structure_coords


def test_structure_distances_are_floored_and_scaled() -> None:
    labels = np.array([0, 0, 1, 1, 2, 2])
    points = np.array([[0.0], [0.1], [0.0], [0.1], [5.0], [5.1]])
    F = np.abs(points - points.T)
    distance = structure_distances(F, labels, 3)
    assert distance.max() == pytest.approx(1.0)
    # structures 0 and 1 have identical clouds: only the floor keeps them apart
    assert distance[0, 1] == pytest.approx(STRUCTURE_DISTANCE_FLOOR)
    coords = structure_embedding(distance)
    embedded = squareform(pdist(coords))
    assert embedded[0, 1] >= 0.5 * STRUCTURE_DISTANCE_FLOOR


def test_search_structure_of_the_multi_structure_example() -> None:
    space = example_space("multi-structure")
    representation = build_representation(space)
    search = search_structure(space, representation)
    assert search is not None
    assert search.n_structures == 6 and search.spec_dim == len(representation.spec_names)
    # joints b..e each have a searched axis, with symmetric limits: sign-invariant
    assert len(search.axes) == 4 and all(axis.sign_invariant for axis in search.axes)
    # the chain of 3 uses the joints of b and c only
    names = representation.spec_names
    used = {names[k].split(".")[0] for k in np.flatnonzero(search.used[0])}
    assert used == {"b", "c"}
    fused = build_representation(space.model_copy(update={"encoding": "fused"}))
    assert search_structure(space, fused) is None


def test_multi_structure_representation(multi: tuple[DesignSpace, Representation]) -> None:
    space, representation = multi
    info: dict[str, Any] = dict(representation.info)
    assert representation.kind == "fused"
    assert info["n_structures"] == 6 and info["n_references"] == 6 * 32
    assert info["fusion_relative_gap"] <= GAP_TOLERANCE
    assert info["fusion_max_violation"] <= VIOLATION_TOLERANCE
    assert "fusion_fallback" not in info
    dim = len(representation.bounds[0])
    assert dim == info["embedding_dim"] <= len(spec_layout(space).names) + 6 - 1
    assert len(representation.affine) == 6
    assert all(
        np.asarray(m).shape == (dim + 1, len(representation.spec_names))
        for m in representation.affine
    )
    # deterministic: a second build (a restarted server) gives the same tables
    again = build_representation(space)
    assert again.ref_coords == representation.ref_coords
    assert again.affine == representation.affine


def test_multi_structure_decodes_and_writes_urdf(multi: tuple[DesignSpace, Representation]) -> None:
    space, representation = multi
    stored = Representation.model_validate_json(representation.model_dump_json())
    for point, structure in zip(stored.ref_coords, stored.ref_structure, strict=True):
        assert decode(space, stored, point).structure_index == structure
    rng = np.random.default_rng(0)
    low, high = np.asarray(stored.bounds)
    seen = set()
    for _ in range(60):
        vector = (low + (high - low) * rng.random(len(low))).tolist()
        design = decode(space, stored, vector)
        seen.add(design.structure_index)
        assert design == decode(space, representation, vector)
        assert design_to_urdf(design).count("<joint ") == len(
            space.tree_structures()[design.structure_index]
        )
        again = decode(space, stored, encode(space, stored, design))
        assert again.structure_index == design.structure_index
        assert np.allclose(
            [j.axis for j in again.joints], [j.axis for j in design.joints], atol=1e-7
        )
    assert len(seen) >= 3  # the box is shared among the structures


def test_all_trees_space_builds_quickly_enough_to_use() -> None:
    body: dict[str, Any] = {
        "type": "design",
        "parts": {"link": {"length": {"low": 0.2, "high": 0.5}}},
        "instances": [{"name": n, "part": "link"} for n in "abcd"],
        "structures": "all",
        "reference_per_structure": 4,
    }
    space = DesignSpace.model_validate(body)
    representation = build_representation(space)
    assert len(representation.structures) == 16
    assert np.asarray(representation.structure_coords).shape[0] == 16
    fused = build_representation(space.model_copy(update={"encoding": "fused"}))
    assert sorted(set(fused.ref_structure)) == list(range(16))
