"""Proposers: a conformance suite for every registered proposer, then each one's own duties.

Requests are built by hand (no server): the proposer interface is arrays in, arrays out.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Any

import httpx
import numpy as np
import pytest
from scipy.optimize import minimize

from adclient.testing.servers import ServerProcess
from adservice.proposers import DEFAULT_PROPOSER, available, get_proposer
from adservice.proposers.base import ProposalRequest, empty_history
from adservice.proposers.gpfit import clear_caches
from adservice.proposers.neldermead import _initial_simplex
from adservice.proposers.simple import sobol_points

BOUNDS = np.array([[-2.0, 0.0, 10.0], [2.0, 5.0, 10.5]])
"""A 3-d box with sides of different lengths and offsets, so scaling mistakes show."""


def bumps(x: np.ndarray) -> np.ndarray:
    """A smooth function on BOUNDS with one clear maximum and one clear minimum."""
    unit = (np.atleast_2d(x) - BOUNDS[0]) / (BOUNDS[1] - BOUNDS[0])
    up = np.exp(-8 * np.sum((unit - [0.7, 0.3, 0.6]) ** 2, axis=1))
    down = np.exp(-8 * np.sum((unit - [0.2, 0.8, 0.3]) ** 2, axis=1))
    return up - down


def history(n: int, *, seed: int = 7) -> tuple[np.ndarray, np.ndarray]:
    unit = np.random.default_rng(seed).random((n, BOUNDS.shape[1]))
    X = BOUNDS[0] + unit * (BOUNDS[1] - BOUNDS[0])
    return X, bumps(X)


def request(
    *,
    X: np.ndarray | None = None,
    y: np.ndarray | None = None,
    count: int = 1,
    seed: int = 0,
    n_issued: int | None = None,
    failed: np.ndarray | None = None,
    pending: np.ndarray | None = None,
    bounds: np.ndarray = BOUNDS,
    **extra: Any,
) -> ProposalRequest:
    dim = bounds.shape[1]
    X = empty_history(dim) if X is None else X
    y = np.zeros(0) if y is None else y
    failed = empty_history(dim) if failed is None else failed
    pending = empty_history(dim) if pending is None else pending
    issued = len(X) + len(failed) + len(pending) if n_issued is None else n_issued
    return ProposalRequest(
        bounds=bounds,
        count=count,
        seed=seed,
        n_issued=issued,
        X=X,
        y=y,
        failed=failed,
        pending=pending,
        **extra,
    )


def unit_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Max-norm distance between two vectors measured in box widths."""
    return float(np.max(np.abs(a - b) / (BOUNDS[1] - BOUNDS[0])))


def min_pairwise_distance(rows: np.ndarray) -> float:
    return min(
        unit_distance(rows[i], rows[j]) for i in range(len(rows)) for j in range(i + 1, len(rows))
    )


PROPOSERS = available()


def test_registry_lists_the_baselines_and_the_default() -> None:
    assert {"qei", "random", "sobol", "nelder-mead", "tpe"} <= set(PROPOSERS)
    assert DEFAULT_PROPOSER == "qei"
    for name in PROPOSERS:
        assert get_proposer(name).name == name
    with pytest.raises(KeyError):
        get_proposer("no-such-proposer")


# -- conformance: every proposer ----------------------------------------------------------


@pytest.mark.parametrize("name", PROPOSERS)
@pytest.mark.parametrize("count", [1, 3])
def test_candidates_have_the_shape_stay_in_bounds_and_are_finite(name: str, count: int) -> None:
    X, y = history(12)
    proposal = get_proposer(name).propose(request(X=X, y=y, count=count))
    assert proposal.candidates.shape == (count, BOUNDS.shape[1])
    assert np.all(np.isfinite(proposal.candidates))
    assert np.all(proposal.candidates >= BOUNDS[0])
    assert np.all(proposal.candidates <= BOUNDS[1])
    assert len(proposal.info) == count
    for entry in proposal.info:
        assert isinstance(entry, dict)
        assert entry["proposer"] == name


@pytest.mark.parametrize("name", PROPOSERS)
def test_identical_requests_give_identical_candidates(name: str) -> None:
    X, y = history(10)
    pending = history(2, seed=99)[0]
    first = get_proposer(name).propose(request(X=X, y=y, count=2, pending=pending, seed=5))
    again = get_proposer(name).propose(request(X=X, y=y, count=2, pending=pending, seed=5))
    np.testing.assert_array_equal(first.candidates, again.candidates)


@pytest.mark.parametrize("name", PROPOSERS)
def test_the_seed_changes_the_start(name: str) -> None:
    a = get_proposer(name).propose(request(count=2, seed=1))
    b = get_proposer(name).propose(request(count=2, seed=2))
    assert not np.array_equal(a.candidates, b.candidates)


@pytest.mark.parametrize("name", PROPOSERS)
@pytest.mark.parametrize("n_issued", [0, 5])
def test_empty_history_is_handled(name: str, n_issued: int) -> None:
    """n_issued 5 with no history: everything issued so far failed to come back yet."""
    proposal = get_proposer(name).propose(request(count=2, n_issued=n_issued))
    assert proposal.candidates.shape == (2, 3)
    assert np.all(np.isfinite(proposal.candidates))
    assert len(proposal.info) == 2


@pytest.mark.parametrize("name", PROPOSERS)
def test_pending_points_are_not_proposed_again(name: str) -> None:
    X, y = history(12)
    pending = get_proposer(name).propose(request(X=X, y=y, count=2)).candidates
    proposal = get_proposer(name).propose(request(X=X, y=y, count=2, pending=pending))
    assert proposal.candidates.shape == (2, 3)
    for candidate in proposal.candidates:
        for point in pending:
            assert unit_distance(candidate, point) > 1e-6


@pytest.mark.parametrize("name", PROPOSERS)
def test_failed_trials_do_not_crash_the_proposer(name: str) -> None:
    X, y = history(10)
    failed = history(4, seed=3)[0]
    proposal = get_proposer(name).propose(request(X=X, y=y, failed=failed, count=2))
    assert proposal.candidates.shape == (2, 3)
    assert np.all(np.isfinite(proposal.candidates))
    for candidate in proposal.candidates:
        for point in failed:
            assert unit_distance(candidate, point) > 1e-6


@pytest.mark.parametrize("name", PROPOSERS)
def test_only_failures_so_far(name: str) -> None:
    failed = history(5, seed=4)[0]
    proposal = get_proposer(name).propose(request(failed=failed, count=1))
    assert proposal.candidates.shape == (1, 3)
    assert np.all(np.isfinite(proposal.candidates))


# -- qei ---------------------------------------------------------------------------------


FAST = {"raw_samples": 256, "num_restarts": 4, "maxiter": 30}
"""Smaller acquisition searches for the tests that check what a proposal is, not how
good (the default: 2048 raw samples, 10 restarts, 100 iterations)."""


def qei_propose(**kwargs: Any):
    return get_proposer("qei").propose(request(**kwargs))


def test_qei_starts_with_the_studys_sobol_points() -> None:
    proposal = qei_propose(count=2, seed=11, n_initial=2)
    expected = BOUNDS[0] + sobol_points(3, 11, 0, 2) * (BOUNDS[1] - BOUNDS[0])
    np.testing.assert_allclose(proposal.candidates, expected)
    assert [entry["method"] for entry in proposal.info] == ["sobol-initial"] * 2


def test_qei_uses_the_model_after_the_initial_design() -> None:
    X, y = history(8)
    proposal = qei_propose(X=X, y=y, count=1, options=FAST)
    (entry,) = proposal.info
    assert entry["method"] == "LogEI"
    assert entry["n_train"] == 8
    noisy = qei_propose(X=X, y=y, count=1, noisy=True, options=FAST)
    assert noisy.info[0]["method"] == "LogEI"
    mc = {**FAST, "acquisition": "mc"}
    mc_batch = qei_propose(X=X, y=y, count=2, options=mc)
    assert [entry["method"] for entry in mc_batch.info] == ["qLogEI"] * 2
    mc_noisy = qei_propose(X=X, y=y, count=1, noisy=True, options=mc)
    assert mc_noisy.info[0]["method"] == "qLogNEI"


def test_qei_batch_of_four_gives_four_distinct_candidates() -> None:
    X, y = history(10)
    proposal = qei_propose(X=X, y=y, count=4, options=FAST)
    assert [entry["method"] for entry in proposal.info] == ["LogEI"] + ["LogEI-believer"] * 3
    assert min_pairwise_distance(proposal.candidates) > 1e-3
    noisy = qei_propose(X=X, y=y, count=4, noisy=True, options=FAST)
    assert min_pairwise_distance(noisy.candidates) > 1e-3
    mc = qei_propose(X=X, y=y, count=4, options={**FAST, "acquisition": "mc"})
    assert min_pairwise_distance(mc.candidates) > 1e-3


@pytest.mark.parametrize("noisy", [False, True])
def test_qei_keeps_away_from_pending_points(noisy: bool) -> None:
    """The point qei wants most, once pending, pushes the next candidate elsewhere."""
    X, y = history(10)
    (favourite,) = qei_propose(X=X, y=y, noisy=noisy).candidates
    (second,) = qei_propose(X=X, y=y, noisy=noisy, pending=favourite[None]).candidates
    assert unit_distance(favourite, second) > 0.02


def test_qei_batch_members_keep_apart_from_pending_points() -> None:
    X, y = history(10)
    pending = qei_propose(X=X, y=y, count=2).candidates
    batch = qei_propose(X=X, y=y, count=3, pending=pending).candidates
    assert min_pairwise_distance(np.vstack([pending, batch])) > 1e-3


def test_qei_first_trials_of_a_batch_are_pending_for_the_rest() -> None:
    """A batch that straddles the initial design: the Sobol rows come first."""
    X, y = history(2)
    proposal = qei_propose(X=X, y=y, count=3, n_initial=3, n_issued=2)
    methods = [entry["method"] for entry in proposal.info]
    assert methods == ["sobol-initial", "LogEI-believer", "LogEI-believer"]
    assert min_pairwise_distance(proposal.candidates) > 1e-3


def test_qei_failed_trials_are_left_out_of_the_model_and_counted_as_pending() -> None:
    X, y = history(10)
    failed = history(3, seed=5)[0]
    proposal = qei_propose(X=X, y=y, failed=failed)
    (entry,) = proposal.info
    assert entry["method"] == "LogEI-believer"
    assert entry["n_train"] == 10
    assert entry["n_pending"] == 3


def test_qei_with_constant_observations_falls_back_to_sobol_and_says_so() -> None:
    X, _ = history(6)
    proposal = qei_propose(X=X, y=np.full(6, 4.2), count=2)
    for entry in proposal.info:
        assert entry["method"] == "sobol-fallback"
        assert "constant" in entry["reason"]
    assert min_pairwise_distance(proposal.candidates) > 1e-3


def test_qei_with_only_duplicate_points_falls_back_to_sobol_and_says_so() -> None:
    X = np.tile(history(1)[0], (5, 1))
    y = np.array([0.1, 0.3, 0.2, 0.25, 0.15])
    proposal = qei_propose(X=X, y=y, count=2)
    for entry in proposal.info:
        assert entry["method"] == "sobol-fallback"
        assert "distinct" in entry["reason"]


def test_qei_with_one_point_falls_back() -> None:
    X, y = history(1)
    (entry,) = qei_propose(X=X, y=y, n_issued=3).info
    assert entry["method"] == "sobol-fallback"


def test_qei_fits_through_some_duplicate_points_and_notes_them() -> None:
    X, y = history(6)
    X = np.vstack([X, X[:3]])
    y = np.concatenate([y, y[:3] + 0.01])
    (entry,) = qei_propose(X=X, y=y).info
    assert entry["method"] == "LogEI"
    assert entry["duplicate_points"] == 3


def test_qei_ignores_non_finite_observations() -> None:
    X, y = history(8)
    y[2] = np.nan
    (entry,) = qei_propose(X=X, y=y).info
    assert entry["method"] == "LogEI"
    assert entry["n_train"] == 7
    assert entry["n_dropped"] == 1


def test_qei_warm_start_and_cache_keep_results_identical() -> None:
    """A cold fit, a cached fit of the same data, and a cold fit again agree exactly."""
    X, y = history(9)
    clear_caches()
    cold = qei_propose(X=X, y=y, seed=21)
    cached = qei_propose(X=X, y=y, seed=21)
    clear_caches()
    cold_again = qei_propose(X=X, y=y, seed=21)
    assert cold.info[0]["fit"] == "cold"
    assert cached.info[0]["fit"] == "cached"
    np.testing.assert_array_equal(cold.candidates, cached.candidates)
    np.testing.assert_array_equal(cold.candidates, cold_again.candidates)
    X2 = np.vstack([X, cold.candidates])
    y2 = np.append(y, bumps(cold.candidates))
    assert qei_propose(X=X2, y=y2, seed=21).info[0]["fit"] == "warm"


@pytest.mark.parametrize("acquisition", ["analytic", "mc"])
def test_qei_noisy_proposals_are_seeded_too(acquisition: str) -> None:
    """qLogNEI prunes its baseline with a sampler of its own, and the raw samples of the
    acquisition optimiser are random: both must be seeded."""
    X, y = history(9)
    pending = history(1, seed=8)[0]
    options = {**FAST, "acquisition": acquisition}
    clear_caches()
    first = qei_propose(X=X, y=y, seed=3, count=2, noisy=True, pending=pending, options=options)
    clear_caches()
    again = qei_propose(X=X, y=y, seed=3, count=2, noisy=True, pending=pending, options=options)
    np.testing.assert_array_equal(first.candidates, again.candidates)
    other_seed = qei_propose(
        X=X, y=y, seed=4, count=2, noisy=True, pending=pending, options=options
    )
    assert not np.array_equal(first.candidates, other_seed.candidates)


def test_qei_options_override_the_optimiser_sizes() -> None:
    X, y = history(8)
    (entry,) = qei_propose(X=X, y=y, options={"num_restarts": 2, "raw_samples": 16}).info
    assert (entry["num_restarts"], entry["raw_samples"]) == (2, 16)


def run_loop(
    objective: Callable[[np.ndarray], np.ndarray], *, budget: int, seed: int
) -> np.ndarray:
    """Ask one at a time, tell the objective (to be maximised): the observed values."""
    X = empty_history(3)
    y = np.zeros(0)
    proposer = get_proposer("qei")
    for _ in range(budget):
        (x,) = proposer.propose(request(X=X, y=y, seed=seed)).candidates
        X = np.vstack([X, x])
        y = np.append(y, objective(x))
    return y


@pytest.mark.slow
@pytest.mark.parametrize("sign", [1.0, -1.0], ids=["maximise-f", "maximise-minus-f"])
def test_qei_finds_the_optimum_of_a_smooth_function_in_either_direction(sign: float) -> None:
    """The service orients y (larger is better); qei must then climb either extremum."""
    y = run_loop(lambda x: sign * bumps(x), budget=25, seed=0)
    assert y.max() > 0.95  # both extrema have |value| ~ 1.0
    assert y.max() > y[:2].max() + 0.2  # clearly better than the initial design


# -- nelder-mead --------------------------------------------------------------------------


def test_nelder_mead_through_ask_tell_follows_scipy_exactly() -> None:
    """Asking one point at a time and telling values reproduces SciPy's own run."""
    bounds = np.array([[0.0, 0.0], [1.0, 1.0]])

    def value(x: np.ndarray) -> float:
        return float((x[0] - 0.3) ** 2 + 2 * (x[1] - 0.6) ** 2)

    x0 = sobol_points(2, 4, 0, 1)[0]
    evaluated: list[np.ndarray] = []

    def recorded(x: np.ndarray) -> float:
        evaluated.append(np.array(x))
        return value(x)

    minimize(
        recorded,
        x0,
        method="Nelder-Mead",
        bounds=[(0.0, 1.0)] * 2,
        options={
            "initial_simplex": _initial_simplex(x0, 0.1),
            "maxfev": 30,
            "xatol": 1e-6,
            "fatol": np.inf,
        },
    )
    X = empty_history(2)
    y = np.zeros(0)
    proposer = get_proposer("nelder-mead")
    for _ in range(30):
        (x,) = proposer.propose(request(X=X, y=y, seed=4, bounds=bounds)).candidates
        X = np.vstack([X, x])
        y = np.append(y, -value(x))
    unique = [
        p for i, p in enumerate(evaluated) if not any(np.array_equal(p, q) for q in evaluated[:i])
    ]
    np.testing.assert_allclose(X[:25], np.array(unique[:25]), atol=1e-12)


def test_nelder_mead_batch_with_pending_speculates_and_says_so() -> None:
    proposer = get_proposer("nelder-mead")
    sequence_X, sequence_y = empty_history(3), np.zeros(0)
    for _ in range(8):
        (x,) = proposer.propose(request(X=sequence_X, y=sequence_y)).candidates
        sequence_X = np.vstack([sequence_X, x])
        sequence_y = np.append(sequence_y, bumps(x))
    (nxt,) = proposer.propose(request(X=sequence_X, y=sequence_y)).candidates
    batch = proposer.propose(request(X=sequence_X, y=sequence_y, pending=nxt[None], count=3))
    assert all(entry.get("speculative") for entry in batch.info)
    assert min_pairwise_distance(np.vstack([nxt[None], batch.candidates])) > 1e-9


# -- through the real service -------------------------------------------------------------


@pytest.fixture(scope="module")
def sqlite_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    """One real adserver on a SQLite file (the proposer does not care which database)."""
    workdir = tmp_path_factory.mktemp("proposers-server")
    server = ServerProcess(database_url=f"sqlite:///{workdir / 'studies.db'}", workdir=workdir)
    server.start()
    yield server
    server.stop()


@pytest.mark.e2e
@pytest.mark.parametrize("direction", ["maximize", "minimize"])
def test_qei_through_http_spreads_batches_and_reports_its_method(
    sqlite_server: ServerProcess, direction: str
) -> None:
    """The service hands qei its pending trials: two batches asked back to back, with
    nothing told in between, are eight distinct designs chosen by the model."""

    params = [
        {"name": name, "low": float(low), "high": float(high)}
        for name, low, high in zip("abc", BOUNDS[0], BOUNDS[1], strict=True)
    ]
    with httpx.Client(base_url=sqlite_server.url, timeout=120) as http:
        study = http.post(
            "/api/v1/studies",
            json={
                "name": f"qei-{direction}",
                "direction": direction,
                "space": {"type": "box", "params": params},
                "proposer": {"name": "qei", "n_initial": 4, "seed": 1, "options": FAST},
            },
        )
        assert study.status_code == 201, study.text
        study_id = study.json()["id"]
        sign = 1.0 if direction == "maximize" else -1.0
        first = http.post(f"/api/v1/studies/{study_id}/ask", json={"count": 4}).json()["trials"]
        assert [t["info"]["method"] for t in first] == ["sobol-initial"] * 4
        for trial in first:
            value = sign * float(bumps(np.array(trial["vector"]))[0])
            told = http.post(f"/api/v1/trials/{trial['id']}/tell", json={"value": value})
            assert told.status_code == 200, told.text
        batches = [
            http.post(f"/api/v1/studies/{study_id}/ask", json={"count": 4}).json()["trials"]
            for _ in range(2)
        ]
    assert [t["info"]["method"] for t in batches[0]] == ["LogEI"] + ["LogEI-believer"] * 3
    assert [t["info"]["method"] for t in batches[1]] == ["LogEI-believer"] * 4
    assert batches[1][0]["info"]["n_pending"] == 4
    vectors = np.array([t["vector"] for batch in batches for t in batch])
    assert min_pairwise_distance(vectors) > 1e-3


PEAK = np.array([0.0, 0.25, 0.75, 0.5])
"""[structure index, three specs]: where ``peak_search``'s acquisition is highest."""


def peak_search(observed: np.ndarray, **taken_tol: float | np.ndarray) -> Any:
    """``acquisition.maximise`` of an acquisition whose one maximum is ``PEAK``, with
    ``observed`` taken (every local search climbs to the peak)."""
    import torch

    from adservice.proposers.acquisition import MixedDomain, maximise

    target = torch.as_tensor(PEAK[1:])

    def acquisition(Z: torch.Tensor) -> torch.Tensor:
        return -((Z.squeeze(-2)[..., 1:] - target) ** 2).sum(dim=-1)

    return maximise(
        acquisition,
        MixedDomain(used=np.ones((1, 3), dtype=bool), pad=0.5),
        raw_count=256,
        num_restarts=4,
        maxiter=50,
        seed=0,
        incumbents=PEAK[None, :],
        tkw={"dtype": torch.float64, "device": torch.device("cpu")},
        taken=observed[None, :],
        **taken_tol,
    )


@pytest.mark.parametrize("offset", [0.0, 1e-7], ids=["at-the-peak", "beside-the-peak"])
def test_the_acquisition_search_answers_a_fresh_point_when_every_search_ends_taken(
    offset: float,
) -> None:
    """An acquisition whose one maximum is an observed point, or within qei's duplicate
    tolerance of one: every local search climbs there, so the answer is the best raw
    sample that is not taken (before, the point itself, which qei then replaced by a
    Sobol fallback: at 1e-7 the search called the peak fresh and qei a duplicate, seen
    on Hartmann6 at 3,000 observations)."""
    from adservice.proposers.acquisition import TAKEN_TOL

    observed = PEAK + np.array([0.0, offset, -offset, offset])
    optimum = peak_search(observed)
    distance = np.max(np.abs(optimum.z - observed))
    assert TAKEN_TOL <= distance < 0.2
    assert optimum.value == pytest.approx(-float(np.sum((optimum.z[1:] - PEAK[1:]) ** 2)))


def test_a_search_in_a_trust_box_answers_what_qei_calls_fresh() -> None:
    """A trust region searches its box's unit coordinates, where qei's duplicate bound
    is TAKEN_TOL / width per column: a point 2e-6 from an observation in a box of width
    0.25 is 5e-7 from it in the model's inputs, a duplicate to qei (before, the search
    called it fresh: 21 of 200 asks at 100,000 observations of Hartmann6 were Sobol
    fallbacks, ``reason: duplicate candidate``)."""
    from adservice.proposers.acquisition import TAKEN_TOL

    width = 0.25
    observed = PEAK + np.array([0.0, 2e-6, -2e-6, 2e-6])  # in the box's unit coordinates

    def in_model_inputs(z: np.ndarray) -> float:
        return float(np.max(np.abs(z - observed)[1:] * width))

    assert in_model_inputs(peak_search(observed).z) < TAKEN_TOL  # the unit box's own bound
    per_column = np.concatenate([[TAKEN_TOL], np.full(3, TAKEN_TOL / width)])
    assert TAKEN_TOL <= in_model_inputs(peak_search(observed, taken_tol=per_column).z) < 0.2


def test_only_numerical_failures_of_a_model_fall_back() -> None:
    """A fit that fails on its numbers degrades to Sobol points; a bug fails the ask
    (caught as any Exception, it looked like an ordinary fall back: issue 37)."""
    import torch
    from botorch.exceptions import BotorchError
    from linear_operator.utils.errors import NotPSDError

    from adservice.proposers.qei import model_errors

    caught = model_errors()
    for numerical in (
        NotPSDError("not p.d."),
        torch.linalg.LinAlgError("singular"),
        torch.OutOfMemoryError("cuda"),
        BotorchError("optimisation"),
        np.linalg.LinAlgError("singular"),
        ValueError("NaN in the input"),
        OverflowError("exp"),
        MemoryError(),
    ):
        assert isinstance(numerical, caught), type(numerical)
    for bug in (
        TypeError(),
        AttributeError(),
        KeyError("x"),
        IndexError(),
        NameError(),
        AssertionError(),
    ):
        assert not isinstance(bug, caught), type(bug)


def test_a_proposer_class_is_looked_up_once(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every ask asks for its study's proposer: after the first, no import machinery."""
    import importlib

    from adservice.proposers import proposer_class
    from adservice.proposers.simple import RandomProposer

    assert proposer_class("random") is RandomProposer

    def no_import(name: str, package: str | None = None) -> None:
        raise AssertionError(f"imported {name} again")

    monkeypatch.setattr(importlib, "import_module", no_import)
    assert get_proposer("random").name == "random"
    with pytest.raises(KeyError):
        proposer_class("no-such-proposer")
