"""qei's structure search (issues 26 and 37): it covers the trees before it models
them, it keeps trying trees it knows little about, it looks at each tree twice before
it trusts one design of it, and its model keeps unseen trees uncertain.

The objectives here are traps: a tree's value adds to a spec term every tree shares,
so a wrong tree keeps scoring a little better as its specs improve, and the best tree
is the one the study's first designs are least likely to land on; or (issue 37) the
specs decide more than the tree and the best tree's optimum is narrow, so its one
random design scores poorly. Requests are built by hand (no server); each study is a
few dozen asks of the real proposer.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np
import pytest
import torch

from adclient.decode import decode
from adclient.design import DesignSpace
from adclient.designs import Design
from adclient.testing.design_objectives import OBJECTIVES, limbs5_space, spec_dominated
from adclient.testing.tree_traps import FLOOR_TRAPS, OTHERS_CEILING
from adservice.proposers import get_proposer
from adservice.proposers.base import ProposalRequest, empty_history, model_inputs, search_vectors
from adservice.proposers.gpfit import fit_outcome
from adservice.proposers.initial import (
    LOOK_CHANCE,
    LOOK_DESIGNS,
    floor_trees,
    structure_order,
    thompson_turn,
)
from adservice.proposers.posterior import Posterior
from adservice.proposers.qei_shared import QEIOptions
from adservice.representation import build_representation, search_structure

TKW: dict[str, Any] = {"dtype": torch.float64, "device": torch.device("cpu")}
LOOKS = {"second_looks": "always"}
JUDGED = {"second_looks": "judged"}
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
    search: Any,
    bounds: np.ndarray,
    X: np.ndarray,
    y: np.ndarray,
    *,
    seed: int,
    count: int = 1,
    options: dict[str, Any] | None = None,
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
        options={"raw_samples": 512, **(options or {})},
    )


def run_study(space: DesignSpace, best: int, evaluations: int, seed: int) -> list[int]:
    """The trees a qei study of ``evaluations`` asks of ``trap_score`` proposes, in order."""
    trees, _, _ = scored_study(space, lambda design: trap_score(design, best), evaluations, seed)
    return trees


def scored_study(
    space: DesignSpace,
    score: Callable[[Design], float],
    evaluations: int,
    seed: int,
    options: dict[str, Any] | None = None,
    until: Callable[[int, float], bool] | None = None,
) -> tuple[list[int], list[float], list[str]]:
    """The trees a qei study of ``evaluations`` asks proposes, in order, their scores
    and each ask's method; ``until(tree, score)``: stop after the first design for which
    it holds."""
    representation = build_representation(space)
    search = search_structure(space, representation)
    bounds = np.asarray(representation.bounds, dtype=np.float64)
    proposer = get_proposer("qei")
    X: list[np.ndarray] = []
    y: list[float] = []
    trees: list[int] = []
    methods: list[str] = []
    for _ in range(evaluations):
        asked = request(search, bounds, np.array(X), np.array(y), seed=seed, options=options)
        proposal = proposer.propose(asked)
        design = decode(space, representation, proposal.candidates[0])
        X.append(proposal.candidates[0])
        y.append(score(design))
        trees.append(design.structure_index)
        methods.append(proposal.info[0]["method"])
        if until is not None and until(trees[-1], y[-1]):
            break
    return trees, y, methods


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


@pytest.mark.slow
def test_a_tree_whose_one_random_design_is_poor_is_still_found() -> None:
    """The specs decide more than the tree (bench's spec-dominated-1: 8 trees, 13 specs;
    tree 2 has a ceiling of 1 and a narrow optimum, every other tree a ceiling of at
    most 0.63). The start's design of tree 2 scores poorly, yet with a second look at
    every tree (``always``), within 30 evaluations, the study goes back to tree 2 and
    finds a design there better than any other tree allows; with ``off`` it ranks the
    trees by their one design each and proposes tree 3 for all 22 model asks. The
    default's Thompson looks do not find tree 2 (their random designs miss an optimum
    this narrow: test_the_default_goes_back_to_trees_whose_first_designs_were_poor is
    the trap they do find), ``judged`` does not on seeds 0 to 2, nor does ``always``
    on seeds 1 and 2 (bench/RESULTS.md, "Judged looks", "Thompson looks, the default")."""
    space = DesignSpace.model_validate(limbs5_space())
    score = spec_dominated(1, 0.05, 0.35, 0.03)
    trees, y, _ = scored_study(space, score, 30, seed=0, options=LOOKS)
    start = dict(zip(trees[:8], y[:8], strict=True))
    assert sorted(start) == list(range(8))
    assert start[2] < 0.5 * max(start.values()), start
    assert trees[8:].count(2) >= 2, trees
    best = int(np.argmax(y))
    # above every other tree's ceiling (0.632); how far above depends on where the
    # optimisers meet the narrow optimum, which the machine's rounding moves (0.652 with
    # torch's arithmetic, 0.645 with NumPy's, 0.635 on another CPU with NumPy's)
    assert score.best == 2 and score.others_ceiling() == pytest.approx(0.632, abs=1e-3)
    assert trees[best] == 2 and y[best] > score.others_ceiling(), (trees, y)


def test_second_looks_choose_among_the_trees_seen_once() -> None:
    """With second looks, after a start of one design per tree (eight trees) and one
    model design, the next ask of two candidates gives a second look then a free choice: the first
    candidate is a tree with one design so far, although the tree seen twice scores
    best, and says so."""
    space = DesignSpace.model_validate(limbs5_space())
    representation = build_representation(space)
    search = search_structure(space, representation)
    assert search is not None
    bounds = np.asarray(representation.bounds, dtype=np.float64)
    score = spec_dominated(1, 0.05, 0.35, 0.03)
    proposer = get_proposer("qei")
    X: list[np.ndarray] = []
    for _ in range(9):
        asked = request(search, bounds, np.array(X), np.arange(len(X), dtype=float), seed=4)
        X.append(proposer.propose(asked).candidates[0])
    trees = np.asarray(X)[:, 0].astype(int)
    y = np.array([score(decode(space, representation, v)) for v in X])
    seen = np.bincount(trees, minlength=8)
    assert sorted(seen.tolist()) == [1] * 7 + [2]
    y[trees == int(np.argmax(seen))] = 1.0  # a free choice would stay on that tree
    asked = request(search, bounds, np.array(X), y, seed=4, count=2, options=LOOKS)
    proposal = proposer.propose(asked)
    look, free = proposal.info
    assert look["second_look"] is True and "second_look" not in free, proposal.info
    assert seen[int(proposal.candidates[0, 0])] == 1


@pytest.mark.parametrize(
    ("objective", "seed", "looks"),
    [("trap", 1, True), ("additive-trap", 0, False)],
)
def test_judged_looks_go_back_only_where_one_design_cannot_rank_the_trees(
    objective: str, seed: int, looks: bool
) -> None:
    """The tree judgement (``second_looks: judged``) at the first look turn
    after a start of one design per tree (the ninth model-phase candidate): on the
    spec-dominated trap the trees' first designs are close and the model, judging each
    tree seen once without its one random design, gives some a fair chance of beating
    the incumbent, so the ask is a second look among those; on additive-trap the
    incumbent's tree leads by far more than one design's spread and no tree gets that
    chance, so the ask is a free choice, as without looks."""
    if objective == "trap":
        space_dict, score = limbs5_space(), spec_dominated(1, 0.05, 0.35, 0.03)
    else:
        space_dict, score = OBJECTIVES[objective].space, OBJECTIVES[objective].score
    space = DesignSpace.model_validate(space_dict)
    representation = build_representation(space)
    search = search_structure(space, representation)
    assert search is not None
    bounds = np.asarray(representation.bounds, dtype=np.float64)
    proposer = get_proposer("qei")
    X: list[np.ndarray] = []
    y: list[float] = []
    for _ in range(9):
        asked = request(search, bounds, np.array(X), np.array(y), seed=seed, options=JUDGED)
        X.append(proposer.propose(asked).candidates[0])
        y.append(score(decode(space, representation, X[-1])))
    proposal = proposer.propose(
        request(search, bounds, np.array(X), np.array(y), seed=seed, options=JUDGED)
    )
    (info,) = proposal.info
    chances = info["tree_chances"]
    once = np.flatnonzero(np.bincount(np.asarray(X)[:, 0].astype(int), minlength=8) == 1)
    assert sorted(int(tree) for tree in chances) == once.tolist()
    if looks:
        assert info.get("second_look") is True, info
        assert max(chances.values()) >= LOOK_CHANCE
        assert chances[str(int(proposal.candidates[0, 0]))] >= LOOK_CHANCE, chances
    else:
        assert "second_look" not in info, info
        assert max(chances.values()) < LOOK_CHANCE, chances


def test_second_looks_take_four_named_choices_and_the_old_flags() -> None:
    """``second_looks`` is ``thompson`` unless a study says ``off``, ``judged`` or
    ``always`` (stored studies' ``true`` and ``false`` mean ``always`` and ``off``);
    anything else is refused, naming it."""
    assert QEIOptions().second_looks == "thompson"
    assert QEIOptions.model_validate({"second_looks": "judged"}).second_looks == "judged"
    assert QEIOptions.model_validate({"second_looks": True}).second_looks == "always"
    assert QEIOptions.model_validate({"second_looks": False}).second_looks == "off"
    assert QEIOptions.model_validate({"second_looks": "off"}).second_looks == "off"
    with pytest.raises(ValueError, match="second_looks"):
        QEIOptions.model_validate({"second_looks": "sometimes"})
    with pytest.raises(ValueError, match="second_looks"):
        QEIOptions.model_validate({"second_looks": 1})


def suite_study(
    name: str, seed: int, evaluations: int, options: dict[str, Any]
) -> tuple[list[int], list[float], list[str]]:
    """A study of the design suite's objective ``name`` as bench/design_suite.py asks
    it (qei's default raw samples, a start of the space's trees)."""
    objective = OBJECTIVES[name]
    space = DesignSpace.model_validate(objective.space)
    return scored_study(space, objective.score, evaluations, seed, {"raw_samples": 2048, **options})


@pytest.mark.slow
def test_the_default_goes_back_to_trees_whose_first_designs_were_poor() -> None:
    """Issue 37's seeded trap, by default: on the suite's unused-specs (seed 4), the
    four trees with limb e reach 1.0 but their start designs all score near their floor
    of 0.3, while every tree without e tops out at 0.5. With ``off`` the study refines a
    tree without e to 0.5 and stays; the default's Thompson looks give e trees random
    designs, and the study ends past random search's lower quartile (0.724)."""
    space = DesignSpace.model_validate(OBJECTIVES["unused-specs"].space)
    with_e = {k for k, edges in enumerate(space.tree_structures()) if any("e" in e for e in edges)}
    assert len(with_e) == 4
    trees, y, _ = suite_study("unused-specs", 4, 30, {"second_looks": "off"})
    start = [(tree, value) for tree, value in zip(trees[:8], y[:8], strict=True) if tree in with_e]
    assert len(start) == 4 and max(value for _, value in start) < 0.36, start
    assert max(y) <= 0.5 + 1e-9
    trees, y, methods = suite_study("unused-specs", 4, 30, {})
    looks = [tree for tree, method in zip(trees, methods, strict=True) if method == "thompson"]
    assert looks and set(looks) <= with_e | set(range(8)), (trees, methods)
    assert any(tree in with_e for tree in looks), (trees, methods)
    assert max(y) > 0.9 and trees[int(np.argmax(y))] in with_e, (trees, y)


@pytest.mark.slow
def test_thompson_looks_end_after_two_per_tree() -> None:
    """Long studies where other trees keep winning draws (unused-specs: the four e
    trees are alike, so each may beat the incumbent's): no tree gets more than two
    looks (Thompson and floor looks together), nor a look once it has three designs,
    and none goes to the incumbent's tree. How many looks one seed takes depends on
    its path (floating point differs between machines: with Thompson looks alone a
    fresh clone on another CPU took 2 where this one took 3), so the rules are checked
    on every look of three seeds; floor looks go to trees whose start design scored on
    the floor, which the start alone decides, so the three seeds look at least three
    times together on any machine."""
    looks = 0
    for seed in range(3):
        trees, y, methods = suite_study("unused-specs", seed, 60, {})
        looked = [k for k, method in enumerate(methods) if method in ("thompson", "floor-look")]
        looks += len(looked)
        per_tree = np.bincount([trees[k] for k in looked], minlength=8)
        assert per_tree.max() <= LOOK_DESIGNS, (seed, per_tree)
        for k in looked:
            assert trees[:k].count(trees[k]) <= LOOK_DESIGNS, (seed, k, trees)
            assert trees[k] != trees[int(np.argmax(y[:k]))], (seed, k, trees, y)
    assert looks >= 3, looks


def test_thompson_turns_are_every_second_model_ask_where_the_start_tried_every_tree() -> None:
    """After a start of 8, candidates 9, 11, 13 ... (numbers 9, 11, ... counted from 0
    at the start's first) are look turns in a space of 8 or 16 trees, none in the start
    and none in a space of 17 trees, whose start leaves one untried."""
    eight, seventeen = np.ones(8, dtype=np.int64), np.ones(17, dtype=np.int64)
    turns = [number for number in range(30) if thompson_turn(eight, number, 8)]
    assert turns == list(range(9, 30, 2))
    assert thompson_turn(np.ones(16, dtype=np.int64), 17, 16)
    assert not any(thompson_turn(seventeen, number, 16) for number in range(60))


def test_a_thompson_look_is_a_random_design_of_the_drawn_tree_unless_it_is_spent() -> None:
    """The look's tree is the one the draw names, with a fresh random design; a draw
    naming the incumbent's tree, or a tree with three designs, leaves the ask to the
    acquisition, as does an ask that is not a look turn."""
    from adservice.proposers.greedy import Greedy

    space = DesignSpace.model_validate(limbs5_space())
    representation = build_representation(space)
    search = search_structure(space, representation)
    assert search is not None
    bounds = np.asarray(representation.bounds, dtype=np.float64)
    X = np.random.default_rng(5).random((9, bounds.shape[1]))
    X[:, 0] = [0, 1, 2, 3, 4, 5, 6, 7, 3]
    y = np.arange(9.0)  # the incumbent is the last, on tree 3
    asked = request(search, bounds, X, y, seed=2, count=1)
    Z = model_inputs(X, bounds, search)
    greedy = Greedy.of(asked, QEIOptions(), bounds, Z, X[:0], Z[::-1], TKW, None)
    counts = np.bincount(X[:, 0].astype(int), minlength=8)
    counts[5] = 3

    def drawing(tree: int) -> Any:
        return lambda trees, step_seed: tree

    look = greedy._thompson_look(counts, 9, 11, drawing(6), greedy.taken)
    assert look is not None and int(look[0]) == 6
    assert not np.allclose(look[1:], Z[6, 1:])
    again = greedy._thompson_look(counts, 9, 12, drawing(6), greedy.taken)
    assert again is not None and not np.allclose(again, look)
    assert greedy._thompson_look(counts, 9, 11, drawing(3), greedy.taken) is None
    assert greedy._thompson_look(counts, 9, 11, drawing(5), greedy.taken) is None
    assert greedy._thompson_look(counts, 10, 11, drawing(6), greedy.taken) is None
    assert greedy._thompson_look(counts, 9, 11, None, greedy.taken) is None


def test_look_counts_take_every_trial_not_only_those_the_model_trains_on() -> None:
    """Whether a tree has had its looks counts every trial of the study: past
    ``max_train`` the model trains on a subset, and failed trials past the latest 32 are
    not pending points, yet both count (a tree with 50 designs got a look when the
    subset held 2 of them)."""
    from adservice.proposers.greedy import Greedy

    space = DesignSpace.model_validate(limbs5_space())
    representation = build_representation(space)
    search = search_structure(space, representation)
    assert search is not None
    bounds = np.asarray(representation.bounds, dtype=np.float64)
    rng = np.random.default_rng(8)
    X = rng.random((400, bounds.shape[1]))
    X[:, 0] = np.arange(400) % 8
    failed = rng.random((40, bounds.shape[1]))
    failed[:, 0] = 3
    pending = rng.random((2, bounds.shape[1]))
    pending[:, 0] = 5
    asked = replace(
        request(search, bounds, X, rng.random(400), seed=1),
        failed=failed,
        pending=pending,
        options={"max_train": 40},
    )
    Z = model_inputs(X, bounds, search)
    kept = Z[:40:7]  # what a subset might hold
    X_pending = np.concatenate([pending, failed[-32:]])
    greedy = Greedy.of(asked, QEIOptions(), bounds, kept, X_pending, kept, TKW, None)
    expected = np.full(8, 50)
    expected[3] += 40
    expected[5] += 2
    assert greedy.structure_counts is not None
    assert greedy.structure_counts.tolist() == expected.tolist()


def test_a_look_inside_spec_constraints_is_drawn_inside_not_moved_onto_their_edge() -> None:
    """With a spec constraint that leaves under 1% of a tree's designs, a Thompson look
    draws until a design satisfies them (as the random proposer does) rather than moving
    one random design onto the nearest face: the looks satisfy the constraints, and most
    lie strictly inside."""
    from adclient.polytope import spec_polytope
    from adservice.proposers.greedy import Greedy

    space = DesignSpace.model_validate(
        {
            **limbs5_space(),
            "spec_constraints": [
                {
                    "terms": {"a.length": 1.0, "b.length": 1.0},
                    "op": "<=",
                    "bound": 0.25,
                }
            ],
        }
    )
    representation = build_representation(space)
    search = search_structure(space, representation)
    polytope = spec_polytope(space, representation)
    assert search is not None and polytope is not None
    bounds = np.asarray(representation.bounds, dtype=np.float64)
    X = np.random.default_rng(5).random((9, bounds.shape[1]))
    X[:, 0] = [0, 1, 2, 3, 4, 5, 6, 7, 3]
    asked = replace(request(search, bounds, X, np.arange(9.0), seed=2), spec_polytope=polytope)
    Z = model_inputs(X, bounds, search)
    greedy = Greedy.of(asked, QEIOptions(), bounds, Z, X[:0], Z[::-1], TKW, None)
    counts = np.bincount(X[:, 0].astype(int), minlength=8)
    looks = [
        greedy._thompson_look(counts, 9, step_seed, lambda trees, seed: 6, greedy.taken)
        for step_seed in range(20)
    ]
    vectors = search_vectors(np.array(looks), bounds, search)
    assert np.all(vectors[:, 0] == 6)
    assert polytope.holds(vectors).all()
    inside = polytope.slack(vectors).max(axis=1) < -1e-6
    assert inside.sum() >= 15, polytope.slack(vectors)


def floor_study(
    name: str, seed: int, options: dict[str, Any], until_found: bool = True
) -> tuple[list[int], list[float], list[str]]:
    """A study of 30 asks of the floor trap ``name`` as bench/design_suite.py asks it;
    ``until_found``: it stops at the first design of the best tree above every other
    tree's ceiling."""
    space, score = FLOOR_TRAPS[name]

    def found(tree: int, value: float) -> bool:
        return until_found and tree == score.best and value > OTHERS_CEILING

    return scored_study(
        DesignSpace.model_validate(space),
        score,
        30,
        seed,
        {"raw_samples": 2048, **options},
        until=found,
    )


def test_the_default_finds_a_best_tree_whose_start_design_scored_on_the_floor() -> None:
    """Issue 61's seeded trap (``floor-8``): the best tree's optimum is a plateau that a
    random design of it misses more often than not, and every other tree tops out at
    0.3 on a broad plateau. On seeds 0 to 13, the covering start (Sobol, the same on
    any machine) puts the best tree's one design on the start's floor on seeds 1, 3, 6
    and 13. Before floor looks every one of them refined a wrong tree for all 22 model
    asks (the GP's output scale, learned from the start's low scores, left the best
    tree no posterior draw above the incumbent: no Thompson look went to it); with
    them, at least three of the four reach a design of the best tree above every other
    tree's ceiling within 30 evaluations (all four here, at asks 10 to 14), and with
    ``floor_looks: false`` the first does not."""
    space, score = FLOOR_TRAPS["floor-8"]
    parsed = DesignSpace.model_validate(space)
    representation = build_representation(parsed)
    search = search_structure(parsed, representation)
    bounds = np.asarray(representation.bounds, dtype=np.float64)
    on_floor = []
    for seed in range(14):
        start = get_proposer("qei").propose(
            request(search, bounds, np.zeros(0), np.zeros(0), seed=seed, count=8)
        )
        designs = [decode(parsed, representation, v) for v in start.candidates]
        trees = np.array([design.structure_index for design in designs])
        floor = floor_trees(trees, np.array([score(d) for d in designs]), 8, 8)
        if floor[score.best]:
            on_floor.append(seed)
    assert on_floor == [1, 3, 6, 13]
    found = 0
    for seed in on_floor:
        trees, y, methods = floor_study("floor-8", seed, {})
        assert trees[:8].count(score.best) == 1
        found += trees[-1] == score.best and y[-1] > OTHERS_CEILING
    assert found >= 3, found
    for seed in on_floor[:1]:
        trees, y, methods = floor_study("floor-8", seed, {"floor_looks": False})
        assert "floor-look" not in methods
        assert max(y) <= OTHERS_CEILING, (seed, trees, y)


def test_a_tree_is_on_the_floor_while_every_design_of_it_lies_in_the_starts_bottom_tenth() -> None:
    """``floor_trees``: the band is the bottom tenth of the start's range (the first
    ``n_start`` scores), whatever later designs score; a tree with one design above it
    is off the floor, an untried tree is not on it, and a start of one score has no
    floor."""
    trees = np.array([0, 1, 2, 3, 1, 2])
    y = np.array([0.0, 0.5, 1.0, 0.08, 0.02, 5.0])
    assert floor_trees(trees, y, 4, 5).tolist() == [True, False, False, True, False]
    assert floor_trees(trees, np.full(6, 0.3), 4, 5).tolist() == [False] * 5
