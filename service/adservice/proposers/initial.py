"""The initial design of ``qei`` (and its multi-objective form): seeded scrambled Sobol
points that cover a typed box's categorical choices, a design space's structures and
the components of its catalogues.

A GP cannot rank a choice or a tree it never saw: with the one-hot kernel it expects
an unseen choice to be average. So the start is long enough to try each, up to
``COVERED_CHOICES``, and deals them to its points.

One random design per tree does not rank the trees either when the specs matter more
than the tree: the best tree's one design can be poor. So with qei's ``second_looks``
at ``thompson`` (the default), every ``SECOND_LOOK_EVERY``-th model ask after the start
of a space whose start tried every tree (``thompson_turn``) is a look turn: the tree a
joint posterior draw favours (``looks.drawn_tree``) gets a random design, unless it is
the incumbent's tree or has more than ``LOOK_DESIGNS`` designs already, when the ask is
a free choice. With ``judged`` or ``always``, every ``SECOND_LOOK_EVERY``-th model ask
after the start (``second_look``) is a look turn while a structure has only one design:
with ``judged`` the ask is a second look among the structures seen once whose chance of
beating the incumbent (``looks.tree_chances``) is at least ``LOOK_CHANCE``, and a free
choice when none has; with ``always`` among every structure seen once. ``off`` never
looks (docs/method.md, "The model's choices").

A start design that scored on the floor says almost nothing of its tree (a narrow
optimum missed looks the same as a poor tree), yet the GP, its output scale learned from
the low scores it has seen, gives such a tree no draw that beats the incumbent. So with
``floor_looks`` (the default, with ``thompson``), a look turn that the draw leaves to the
model goes to a tree whose one design is on the start's floor (``floor_trees``) instead:
one more random design of it.
"""

from __future__ import annotations

import numpy as np

from adservice.proposers.base import ProposalRequest, SearchStructure
from adservice.proposers.simple import scale_to_bounds, sobol_points

COVERED_CHOICES = 16
"""The most choices of a categorical param, or structures of a design space, the
initial design makes sure to try."""


SECOND_LOOK_EVERY = 2
"""Every this many model asks after the start, one is a look turn (``second_look``,
``thompson_turn``)."""
LOOK_DESIGNS = 2
"""A Thompson look goes to a tree with at most this many designs (observed, failed or
pending), so a long study's looks end: a tree gets at most two beyond its start design."""
FLOOR_BAND = 0.1
"""A start design scored on the floor when it lies in this bottom share of the range of
the start's scores (``floor_trees``)."""
LOOK_CHANCE = 0.2
"""A judged second look goes to the trees seen once whose chance of beating the incumbent
(``looks.tree_chances``) is at least this."""


def initial_points(request: ProposalRequest, bounds: np.ndarray, count: int) -> np.ndarray:
    """The study's initial points numbers ``n_issued`` to ``n_issued + count``."""
    unit = sobol_points(request.dim, request.seed, request.n_issued, count)
    return covering_choices(scale_to_bounds(unit, bounds), request)


def initial_count(request: ProposalRequest) -> int:
    """``n_initial``, or enough initial points to try every choice of each categorical
    param and every structure of a design space (up to ``COVERED_CHOICES`` of each):
    the model knows nothing of a choice it never saw and, with the one-hot kernel,
    expects it to be average, so a study started on two choices of four kept to them
    (bench/RESULTS.md); a design study started on two trees of eight kept
    to the first good one."""
    most = 0
    if request.box is not None and request.box.categorical:
        most = max(request.box.categorical.values())
    if request.structure is not None:
        most = max(most, request.structure.n_structures)
        for choice in request.structure.choices:
            most = max(most, len(choice.points))
    return max(request.n_initial, min(most, COVERED_CHOICES))


def structure_order(search: SearchStructure, seed: int) -> np.ndarray:
    """The order in which the initial design deals the structures: from a seeded first
    structure, each next one the farthest (in the fused geometry) from those already
    dealt, ties broken by a seeded shuffle; so when only some can be covered, they
    spread over the kinds of tree instead of clustering."""
    coords = np.asarray(search.structure_coords, dtype=np.float64)
    count = len(coords)
    rng = np.random.default_rng([seed, 26])
    shuffled = rng.permutation(count)
    order = [int(shuffled[0])]
    nearest = np.linalg.norm(coords - coords[order[0]], axis=1)
    for _ in range(count - 1):
        candidates = shuffled[np.argsort(-nearest[shuffled], kind="stable")]
        chosen = int(candidates[0])
        order.append(chosen)
        nearest = np.minimum(nearest, np.linalg.norm(coords - coords[chosen], axis=1))
    return np.asarray(order, dtype=np.int64)


def covering_choices(points: np.ndarray, request: ProposalRequest) -> np.ndarray:
    """Initial Sobol points (numbers ``n_issued`` on) with each categorical column dealt
    round-robin through a seeded order of its choices, as design structures are dealt
    to raw samples (``acquisition.raw_samples``), then snapped; a design space's
    structure index dealt through ``structure_order``."""
    numbers = request.n_issued + np.arange(len(points))
    search = request.structure
    if search is not None and search.n_structures > 1:
        points = points.copy()
        order = structure_order(search, request.seed)
        points[:, 0] = order[numbers % len(order)]
    if search is not None and search.choices:
        points = points.copy()
        offset = 1 if search.n_structures > 1 else 0
        for number, choice in enumerate(search.choices):
            columns = [offset + column for column in choice.columns]
            stream = np.random.default_rng([request.seed, 28, number])
            dealt = stream.permutation(len(choice.points))
            points[:, columns] = choice.points[dealt[numbers % len(dealt)]]
    box = request.box
    if box is None:
        return points
    points = points.copy()
    for column, count in box.categorical.items():
        order = np.random.default_rng([request.seed, column]).permutation(count)
        points[:, column] = order[numbers % count]
    return box.snap(points)


def second_look(counts: np.ndarray, number: int, n_start: int) -> np.ndarray | None:
    """The structures the study's candidate number ``number`` must choose among, or None
    for a free choice: after a start of ``n_start`` designs, every
    ``SECOND_LOOK_EVERY``-th model candidate (the second, fourth, ...) chooses among
    the structures with exactly one design so far (``counts``: observed, failed and
    pending designs per structure, this batch's earlier candidates included), while
    any has; a structure never tried is left to the model, which holds it uncertain."""
    model_number = number - n_start
    if model_number < 0 or model_number % SECOND_LOOK_EVERY != SECOND_LOOK_EVERY - 1:
        return None
    once = np.flatnonzero(counts == 1)
    return once if len(once) else None


def thompson_turn(counts: np.ndarray, number: int, n_start: int) -> bool:
    """Whether the study's candidate number ``number`` is a Thompson look turn: every
    ``SECOND_LOOK_EVERY``-th model candidate after a start of ``n_start`` designs, in a
    space of at most ``COVERED_CHOICES`` structures (``counts``: designs per structure).
    Past that many, the start leaves trees untried, the model already holds those
    uncertain, and some tree's draw nearly always beats the incumbent's, so looks would
    take every other ask (bench/RESULTS.md, "Thompson sampling across trees")."""
    model_number = number - n_start
    return (
        len(counts) <= COVERED_CHOICES
        and model_number >= 0
        and model_number % SECOND_LOOK_EVERY == SECOND_LOOK_EVERY - 1
    )


def floor_trees(trees: np.ndarray, y: np.ndarray, n_start: int, n_structures: int) -> np.ndarray:
    """Per structure, whether every observed design of it (``trees``, ``y``: the study's
    observations in the order told) scored on the floor of the start: in the bottom
    ``FLOOR_BAND`` of the range of the first ``n_start`` observations' scores. A
    structure never observed is not on the floor (the model holds it uncertain); with
    fewer than two start scores, or a start of one score, none is."""
    floor = np.zeros(n_structures, dtype=bool)
    start = y[:n_start]
    if len(start) < 2 or np.ptp(start) <= 0:
        return floor
    band = float(start.min() + FLOOR_BAND * np.ptp(start))
    seen = np.bincount(trees, minlength=n_structures) > 0
    above = np.bincount(trees, weights=(y > band).astype(np.float64), minlength=n_structures)
    return seen & (above == 0)
