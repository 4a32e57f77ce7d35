"""Issue 38: the transfer choice is a pure function of the rows the repository returns
(adservice.services.transfer), checked here without a database or a server: a source is
of the job's own tree, among the ``among`` best (one objective, rows best first) or the
non-dominated (several), and the nearest on the coordinates its tree uses.
tests/service/test_transfer.py checks the same choice through a real server."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from adclient.decode import spec_vector
from adclient.design import DesignSpace
from adclient.objectives import Direction, Outcomes
from adclient.schemas import StudyCreate, TransferSource
from adservice.repository.transfer import SourceRow
from adservice.representation import build_representation
from adservice.services.transfer import choose_source, nearest

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
BOX = np.array([[0.0, 0.0], [1.0, 2.0]])
ONE = Outcomes()
TWO = Outcomes(directions=(Direction.maximize, Direction.minimize), names=("a", "b"))


def box_choice(
    vector: list[float], rows: list[SourceRow], *, among: int, outcomes: Outcomes
) -> TransferSource | None:
    return choose_source(
        vector, rows, among=among, representation=None, ties={}, bounds=BOX, outcomes=outcomes
    )


def test_one_objective_takes_the_nearest_of_the_first_among_rows() -> None:
    """Rows come best first: the nearest of the first two, never the third (nearer)."""
    rows = [SourceRow(1, [0.9, 1.8]), SourceRow(2, [0.5, 1.0]), SourceRow(3, [0.1, 0.2])]
    source = box_choice([0.1, 0.2], rows, among=2, outcomes=ONE)
    assert source is not None and source.trial_id == 2
    # normalised by the box: (0.4, 0.4) apart on both coordinates
    assert np.isclose(source.distance, 0.4)
    assert box_choice([0.1, 0.2], [], among=2, outcomes=ONE) is None


def test_several_objectives_take_the_nearest_non_dominated_row() -> None:
    """Row 3 is nearest but dominated by row 1; row 4 lacks a value: row 2 is chosen."""
    rows = [
        SourceRow(1, [1.0, 2.0], [5.0, 1.0]),
        SourceRow(2, [0.5, 1.0], [1.0, 0.0]),
        SourceRow(3, [0.0, 0.0], [4.0, 2.0]),
        SourceRow(4, [0.0, 0.1], [9.0, None]),
    ]
    source = box_choice([0.0, 0.0], rows, among=1, outcomes=TWO)
    assert source is not None and source.trial_id == 2


def test_a_source_is_of_the_designs_own_tree() -> None:
    """examples/multi-structure.yaml: the best row of another tree is never chosen."""
    body = StudyCreate.model_validate(
        yaml.safe_load((EXAMPLES / "multi-structure.yaml").read_text())
    )
    assert isinstance(body.space, DesignSpace)
    representation = build_representation(body.space)
    low, high = bounds = np.asarray(representation.bounds, dtype=np.float64)
    rng = np.random.default_rng(0)
    vectors = [(low + rng.random(len(low)) * (high - low)).tolist() for _ in range(60)]
    trees = [spec_vector(representation, vector)[0] for vector in vectors]
    target = vectors[0]
    others = [i for i in range(1, 60) if trees[i] != trees[0]]
    same = [i for i in range(1, 60) if trees[i] == trees[0]]
    assert others and same
    rows = [SourceRow(i, vectors[i]) for i in others + same]
    source = choose_source(
        target,
        rows,
        among=1,
        representation=representation,
        ties=body.space.ties(),
        bounds=bounds,
        outcomes=ONE,
    )
    assert source is not None and source.trial_id == same[0]


def test_nearest_compares_only_the_used_coordinates() -> None:
    specs = np.array([0.0, 0.0, 0.0])
    others = [np.array([0.1, 0.1, 1.0]), np.array([0.5, 0.5, 0.0])]
    assert nearest(specs, others, np.array([True, True, False]))[0] == 0
    assert nearest(specs, others, np.array([True, True, True]))[0] == 1
    assert nearest(specs, others, np.zeros(3, dtype=bool)) == (0, 0.0)
