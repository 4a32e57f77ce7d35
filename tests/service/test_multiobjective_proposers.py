"""Proposers with several objectives and outcome constraints (issue 17), as arrays.

No server: requests are built by hand with ``objectives`` (each column maximised),
``ref_point`` and ``slacks`` (<= 0 satisfied). Problems: ZDT1 (d = 4) and a
constrained toy (maximise -||x||^2 subject to x0 >= 0.5).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
import torch
from botorch.utils.multi_objective.hypervolume import Hypervolume
from botorch.utils.multi_objective.pareto import is_non_dominated

from adservice.proposers import available, get_proposer, proposer_class
from adservice.proposers.base import ProposalRequest, SearchStructure, empty_history
from adservice.proposers.gpfit import clear_caches
from adservice.proposers.memory import memory_need
from adservice.proposers.multiobjective import observed_front, reference_point
from adservice.proposers.qei_shared import QEIOptions

D = 4
UNIT = np.array([np.zeros(D), np.ones(D)])
TOY = np.array([-np.ones(3), np.ones(3)])
FAST = {"raw_samples": 256, "num_restarts": 4, "mc_samples": 64, "maxiter": 30}
"""Smaller searches for the tests that only check what a proposal is."""


def zdt1(X: np.ndarray) -> np.ndarray:
    """ZDT1's two objectives (minimised), negated: each column maximised."""
    f1 = X[:, 0]
    g = 1.0 + 9.0 * X[:, 1:].mean(axis=1)
    return -np.column_stack([f1, g * (1.0 - np.sqrt(f1 / g))])


def toy(X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """-||x||^2 and the slack of x0 >= 0.5 (the optimum -0.25 at (0.5, 0, 0))."""
    return -np.sum(X**2, axis=1), 0.5 - X[:, :1]


def hypervolume(objectives: np.ndarray, ref: np.ndarray) -> float:
    """Hypervolume (maximised objectives) of the rows that dominate ``ref``."""
    Y = torch.as_tensor(objectives, dtype=torch.float64)
    Y = Y[(torch.as_tensor(ref) < Y).all(dim=1)]
    if len(Y) == 0:
        return 0.0
    front = Y[is_non_dominated(Y)]
    return float(Hypervolume(torch.as_tensor(ref, dtype=torch.float64)).compute(front))


def mo_request(
    X: np.ndarray,
    objectives: np.ndarray,
    *,
    count: int = 1,
    bounds: np.ndarray = UNIT,
    seed: int = 0,
    pending: np.ndarray | None = None,
    failed: np.ndarray | None = None,
    **extra: Any,
) -> ProposalRequest:
    dim = bounds.shape[1]
    pending = empty_history(dim) if pending is None else pending
    failed = empty_history(dim) if failed is None else failed
    return ProposalRequest(
        bounds=bounds,
        count=count,
        seed=seed,
        n_issued=len(X) + len(pending) + len(failed),
        X=X,
        y=objectives[:, 0].copy(),
        failed=failed,
        pending=pending,
        n_initial=6,
        objectives=objectives,
        **extra,
    )


def toy_request(X: np.ndarray, *, count: int = 1, **extra: Any) -> ProposalRequest:
    y, slacks = toy(X)
    dim = X.shape[1]
    return ProposalRequest(
        bounds=TOY,
        count=count,
        seed=extra.pop("seed", 0),
        n_issued=len(X),
        X=X,
        y=y,
        failed=empty_history(dim),
        pending=extra.pop("pending", empty_history(dim)),
        n_initial=6,
        slacks=slacks,
        **extra,
    )


def history(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    X = np.random.default_rng(seed).random((n, D))
    return X, zdt1(X)


def test_which_proposers_take_several_objectives_and_constraints() -> None:
    flags = {
        name: (proposer_class(name).multi_objective, proposer_class(name).constrained)
        for name in available()
    }
    assert flags == {
        "nelder-mead": (False, False),
        "qei": (True, True),
        "random": (True, True),
        "sobol": (True, True),
        "tpe": (True, True),
    }


@pytest.mark.parametrize("name", ["qei", "qei-mc", "tpe", "random", "sobol"])
def test_a_multi_objective_batch_is_in_bounds_and_away_from_pending_points(name: str) -> None:
    X, Y = history(14)
    pending = np.random.default_rng(5).random((2, D))
    options = {"qei": FAST, "qei-mc": {**FAST, "acquisition": "mc"}}.get(name, {})
    name = name.removesuffix("-mc")
    request = mo_request(X, Y, count=3, pending=pending, options=options)
    proposal = get_proposer(name).propose(request)
    rows = proposal.candidates
    assert rows.shape == (3, D) and np.all(np.isfinite(rows))
    assert np.all(rows >= 0.0) and np.all(rows <= 1.0)
    for row in rows:
        assert np.min(np.max(np.abs(pending - row), axis=1)) > 1e-6
    assert len({tuple(np.round(row, 9)) for row in rows}) == 3
    if name == "qei":
        method = "qLogNEHVI" if options.get("acquisition") == "mc" else "LogEHVI-believer"
        assert [info["method"] for info in proposal.info] == [method] * 3
        assert proposal.info[0]["n_pending"] == 2


def test_qei_infers_the_reference_point_from_the_observations() -> None:
    X, Y = history(12)
    proposal = get_proposer("qei").propose(mo_request(X, Y, options=FAST))
    info = proposal.info[0]
    nadir, ideal = Y.min(axis=0), Y.max(axis=0)
    assert info["acquisition"] == "LogEHVI"
    assert info["ref_point_source"] == "inferred"
    assert info["lengthscale_prior"] == "unit"
    np.testing.assert_allclose(info["ref_point"], nadir - 0.1 * (ideal - nadir))
    front = Y[is_non_dominated(torch.as_tensor(Y)).numpy()]
    assert info["n_pareto"] == len(front)


def test_qei_uses_a_given_reference_point() -> None:
    X, Y = history(12)
    ref = np.array([-1.5, -12.0])
    info = get_proposer("qei").propose(mo_request(X, Y, ref_point=ref, options=FAST)).info[0]
    assert info["ref_point"] == [-1.5, -12.0] and info["ref_point_source"] == "given"


def test_infeasible_trials_never_count_toward_the_front_or_the_reference_point() -> None:
    objectives = np.array([[0.0, 0.0], [1.0, 5.0], [1.0, 1.0], [2.0, 0.5], [-3.0, 0.2]])
    feasible = np.array([True, False, True, True, False])
    assert observed_front(objectives, feasible).tolist() == [2, 3]
    ref, source = reference_point(objectives, feasible, None)
    np.testing.assert_allclose(ref, [0.0 - 0.2, 0.0 - 0.1])
    assert source == "inferred"
    # while nothing is feasible, the reference point comes from every observation
    ref, _ = reference_point(objectives, np.zeros(5, dtype=bool), None)
    np.testing.assert_allclose(ref, [-3.0 - 0.5, 0.0 - 0.5])


@pytest.mark.parametrize("acquisition", ["analytic", "mc"])
def test_qei_with_objectives_and_a_constraint_counts_only_feasible_trials(
    acquisition: str,
) -> None:
    X, Y = history(14, seed=3)
    slacks = 0.5 - X[:, :1]
    options = {**FAST, "acquisition": acquisition}
    request = mo_request(X, Y, count=2, slacks=slacks, options=options)
    clear_caches()  # each outcome's own fit, not the other parametrisation's
    proposal = get_proposer("qei").propose(request)
    info = proposal.info[0]
    feasible = slacks[:, 0] <= 0
    expected = {"analytic": "LogEHVI", "mc": "qLogNEHVI"}[acquisition]
    assert info["acquisition"] == expected and info["n_constraints"] == 1
    assert info["n_feasible"] == int(feasible.sum())
    assert info["n_pareto"] == len(observed_front(Y, feasible))
    assert info["fits"] == ["cold", "cold", "cold"]


def test_failed_trials_are_pending_points_not_observations() -> None:
    X, Y = history(12)
    failed = np.random.default_rng(9).random((3, D))
    proposal = get_proposer("qei").propose(mo_request(X, Y, failed=failed, options=FAST))
    info = proposal.info[0]
    assert info["n_train"] == 12 and info["n_pending"] == 3
    assert np.min(np.max(np.abs(failed - proposal.candidates[0]), axis=1)) > 1e-6


def test_identical_multi_objective_requests_give_identical_candidates() -> None:
    X, Y = history(12)
    first = get_proposer("qei").propose(mo_request(X, Y, count=2, options=FAST))
    second = get_proposer("qei").propose(mo_request(X, Y, count=2, options=FAST))
    np.testing.assert_array_equal(first.candidates, second.candidates)


def test_before_n_initial_observations_the_start_is_space_filling() -> None:
    X, Y = history(3)
    proposal = get_proposer("qei").propose(mo_request(X, Y, count=4, options=FAST))
    methods = [info["method"] for info in proposal.info]
    assert methods == ["sobol-initial"] * 3 + ["LogEHVI-believer"]


def test_two_structures_with_two_objectives() -> None:
    """A design space of two structures (the mixed representation: the index, then
    three specs, the first structure using two of them) works with LogEHVI."""
    search = SearchStructure(
        structure_coords=np.array([[0.0], [1.0]]),
        used=np.array([[True, True, False], [True, True, True]]),
        spec_low=np.zeros(3),
        spec_high=np.ones(3),
    )
    bounds = np.array([[-0.5, 0.0, 0.0, 0.0], [1.5, 1.0, 1.0, 1.0]])
    rng = np.random.default_rng(4)
    X = np.column_stack([np.arange(16) % 2, rng.random((16, 3))])
    X[X[:, 0] == 0, 3] = 0.5  # the unused slot at the pad
    Y = np.column_stack(
        [
            -np.sum((X[:, 1:3] - 0.3) ** 2, axis=1) - 0.2 * X[:, 0],
            -np.sum((X[:, 1:3] - 0.7) ** 2, axis=1),
        ]
    )
    tpe = get_proposer("tpe").propose(mo_request(X, Y, count=2, bounds=bounds, structure=search))
    assert np.all(tpe.candidates >= bounds[0]) and np.all(tpe.candidates <= bounds[1])
    proposal = get_proposer("qei").propose(
        mo_request(X, Y, count=2, bounds=bounds, structure=search, options=FAST)
    )
    info, rows = proposal.info[0], proposal.candidates
    assert info["acquisition"] == "LogEHVI" and "structure_correlation" in info
    assert rows.shape == (2, 4) and set(rows[:, 0]) <= {0.0, 1.0}
    assert np.all(rows[rows[:, 0] == 0, 3] == 0.5)  # what structure 0 does not use


@pytest.mark.parametrize("acquisition", ["analytic", "mc"])
def test_one_objective_with_a_constraint_uses_the_feasible_incumbent(acquisition: str) -> None:
    X = np.random.default_rng(2).uniform(-1, 1, (12, 3))
    y, slacks = toy(X)
    options = {"acquisition": acquisition, **FAST}
    proposal = get_proposer("qei").propose(toy_request(X, count=2, options=options))
    info = proposal.info[0]
    expected = {"analytic": "LogCEI", "mc": "qLogEI"}[acquisition]
    assert info["acquisition"] == expected and info["n_constraints"] == 1
    assert info["best_feasible"] == float(y[slacks[:, 0] <= 0].max())
    assert proposal.candidates.shape == (2, 3)
    assert proposal.info[1]["method"].startswith(expected)


def test_with_no_feasible_trial_yet_qei_looks_for_feasibility() -> None:
    X = np.random.default_rng(6).uniform(-1, 0.2, (10, 3))
    proposal = get_proposer("qei").propose(toy_request(X, count=2))
    assert [info["acquisition"] for info in proposal.info] == ["LogPoF", "LogPoF"]
    assert np.all(proposal.candidates[:, 0] > 0.2)


def test_memory_estimate_counts_every_outcome() -> None:
    options = QEIOptions()
    one = memory_need(options, dim=4, count=1, n_train=80, n_pending=0)
    two = memory_need(options, dim=4, count=1, n_train=80, n_pending=0, n_objectives=2)
    constrained = memory_need(
        options, dim=4, count=1, n_train=80, n_pending=0, n_objectives=2, n_constraints=1
    )
    assert one.bytes < two.bytes < constrained.bytes
    assert "2 outcomes" in two.describe()


@pytest.mark.parametrize("constrained", [False, True])
def test_tpe_runs_multi_objective_and_constrained(constrained: bool) -> None:
    rng = np.random.default_rng(1)
    X = rng.random((30, D))
    Y = zdt1(X)
    extra = {"slacks": 0.5 - X[:, :1]} if constrained else {}
    proposal = get_proposer("tpe").propose(mo_request(X, Y, count=3, **extra))
    assert proposal.candidates.shape == (3, D)
    assert [info["method"] for info in proposal.info] == ["tpe"] * 3


def test_constrained_tpe_keeps_to_the_feasible_region() -> None:
    X = np.random.default_rng(0).uniform(-1, 1, (10, 3))
    feasible = 0
    for _ in range(20):
        (row,) = get_proposer("tpe").propose(toy_request(X, seed=1)).candidates
        feasible += row[0] >= 0.5
        X = np.vstack([X, row])
    assert feasible >= 10  # a uniform draw is feasible a quarter of the time


@pytest.mark.slow
def test_constrained_qei_proposals_are_mostly_feasible_once_the_constraint_is_learned() -> None:
    X = np.random.default_rng(0).uniform(-1, 1, (6, 3))
    proposer = get_proposer("qei")
    for _ in range(10):
        (row,) = proposer.propose(toy_request(X, seed=1)).candidates
        X = np.vstack([X, row])
    late = X[-6:]
    assert np.sum(late[:, 0] >= 0.5 - 1e-6) >= 5
    y, slacks = toy(X)
    assert y[slacks[:, 0] <= 0].max() > -0.3  # the optimum is -0.25


@pytest.mark.slow
def test_qei_gains_more_hypervolume_than_random_on_zdt1() -> None:
    """6 Sobol points, then 5 asks of 2 (16 evaluations, the smaller searches of FAST);
    random: 16 uniform points. Hypervolume against ZDT1's usual reference point (11, 11)
    (BoTorch's), in the maximised orientation."""
    ref = np.array([-11.0, -11.0])
    wins = 0
    for seed in [0, 1, 2]:
        X = np.empty((0, D))
        while len(X) < 16:
            request = mo_request(X, zdt1(X), count=6 if len(X) < 6 else 2, seed=seed)
            request = ProposalRequest(**{**request.__dict__, "options": FAST})
            X = np.vstack([X, get_proposer("qei").propose(request).candidates])
        random_X = np.random.default_rng(100 + seed).random((16, D))
        wins += hypervolume(zdt1(X), ref) > hypervolume(zdt1(random_X), ref)
    assert wins >= 2


def _fitted(X: np.ndarray, columns: np.ndarray) -> list[Any]:
    """A GP per column on the box's model inputs (index 0, then X), as qei fits them."""
    from botorch.models import SingleTaskGP
    from botorch.models.transforms.outcome import Standardize

    from adservice.proposers.gpmodel import design_kernel
    from adservice.proposers.likelihood import fit_map

    Z = torch.as_tensor(np.column_stack([np.zeros(len(X)), X]))
    models = []
    for column in columns.T:
        model = SingleTaskGP(
            Z,
            torch.as_tensor(column).unsqueeze(-1),
            covar_module=design_kernel(None, X.shape[1], kernel="matern", dtype=torch.float64),
            outcome_transform=Standardize(m=1),
        )
        fit_map(model)
        models.append(model.eval())
    return models


def _inputs(X: np.ndarray) -> torch.Tensor:
    return torch.as_tensor(np.concatenate([np.zeros((*X.shape[:-1], 1)), X], axis=-1))


@pytest.mark.parametrize("m", [2, 3])
def test_analytic_log_ehvi_is_the_log_of_botorchs_expected_hypervolume_improvement(
    m: int,
) -> None:
    """The exact expectation: against BoTorch's analytic EHVI (``ExpectedHypervolume
    Improvement``, same GPs, same box decomposition of the observed front), and with a
    constraint, plus the log probability that the constraint's GP is <= 0."""
    from botorch.acquisition.multi_objective.analytic import ExpectedHypervolumeImprovement
    from botorch.models.model_list_gp_regression import ModelListGP
    from botorch.utils.multi_objective.box_decompositions.non_dominated import (
        FastNondominatedPartitioning,
    )

    from adservice.proposers.multiobjective import AnalyticLogEHVI

    rng = np.random.default_rng(m)
    X = rng.random((16, D))
    Y = np.column_stack([zdt1(X), -np.sum((X - 0.5) ** 2, axis=1)])[:, :m]
    slack = X[:, 1:2] - 0.6
    models = _fitted(X, np.column_stack([Y, slack]))
    ref = reference_point(Y, np.ones(16, dtype=bool), None)[0]
    feasible = np.ones(16, dtype=bool)
    ours = AnalyticLogEHVI(models[:m], [], _inputs(X), Y, feasible, False, ref)
    acquisition, name = ours.step(None)
    partitioning = FastNondominatedPartitioning(
        ref_point=torch.as_tensor(ref), Y=torch.as_tensor(Y)
    )
    theirs = ExpectedHypervolumeImprovement(
        ModelListGP(*models[:m]), ref_point=ref.tolist(), partitioning=partitioning
    )
    points = _inputs(rng.random((64, 1, D)))
    with torch.no_grad():
        expected = theirs(points)
        got = acquisition(points)
    assert name == "LogEHVI"
    # BoTorch's EHVI is not in log space: far from the front it underflows (to 0 or to
    # a few significant digits); the log keeps a value there, far below the rest
    sure = expected > 1e-12
    assert int(sure.sum()) >= 32
    torch.testing.assert_close(got[sure], expected[sure].log(), rtol=1e-6, atol=1e-9)
    assert torch.all(got[~sure] < -20)

    constrained = AnalyticLogEHVI(models[:m], models[m:], _inputs(X), Y, feasible, False, ref)
    with torch.no_grad():
        mean = models[m].posterior(points).mean.reshape(-1)
        sigma = models[m].posterior(points).variance.sqrt().reshape(-1)
        log_feasible = torch.special.log_ndtr(-mean / sigma)
        torch.testing.assert_close(
            constrained.step(None)[0](points)[sure],
            (expected.log() + log_feasible)[sure],
            rtol=1e-6,
            atol=1e-9,
        )


def test_analytic_log_ehvi_believes_pending_points_onto_the_front() -> None:
    """A pending point is believed at the model's mean: proposing it again, or next to
    it, gains far less than without it."""
    from adservice.proposers.multiobjective import AnalyticLogEHVI

    X, Y = history(16, seed=7)
    models = _fitted(X, Y)
    ref = reference_point(Y, np.ones(16, dtype=bool), None)[0]
    acquisition = AnalyticLogEHVI(models, [], _inputs(X), Y, np.ones(16, dtype=bool), False, ref)
    point = _inputs(np.array([[[0.3, 0.05, 0.05, 0.05]]]))
    alone, _ = acquisition.step(None)
    believed, name = acquisition.step(point[0])
    with torch.no_grad():
        assert name == "LogEHVI-believer"
        assert float(believed(point)) < float(alone(point)) - 2.0  # 7 times less


@pytest.mark.parametrize("several", [False, True])
def test_the_gps_of_several_objectives_have_the_unit_length_scale_prior(several: bool) -> None:
    """gpmodel.UNIT_LENGTHSCALE_PRIOR for a study of several objectives; one objective
    keeps BoTorch's dimension-scaled prior (median exp(sqrt(2) + ln(4) / 2) at d = 4)."""
    import math

    from adservice.proposers.gpfit import fit_outcome
    from adservice.proposers.gpmodel import UNIT_LENGTHSCALE_PRIOR

    X, Y = history(10)
    request = mo_request(X, Y if several else Y[:, :1])
    tkw = {"dtype": torch.float64, "device": torch.device("cpu")}
    model, _ = fit_outcome(request, QEIOptions(), UNIT, X, Y[:, 0].copy(), tkw, None, "x")
    prior = model.covar_module.spec.lengthscale_prior
    expected = UNIT_LENGTHSCALE_PRIOR[0] if several else math.sqrt(2.0) + 0.5 * math.log(D)
    assert float(prior.loc) == pytest.approx(expected)
