"""qei on design spaces: the structure kernel, axis features, and the mixed acquisition.

Requests are built by hand from the examples' spaces (no server), except the last test,
which asks a real ``adserver`` and checks that what it stores is what the decoder reads.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
import torch
import yaml

from adclient.decode import PAD, decode, spec_layout
from adclient.design import DesignSpace
from adclient.designs import Representation
from adclient.schemas import StudyCreate
from adclient.testing.servers import ServerProcess
from adservice.proposers import get_proposer
from adservice.proposers.base import (
    AxisColumns,
    ProposalRequest,
    SearchStructure,
    empty_history,
    model_inputs,
)
from adservice.proposers.gpmodel import SpecFeatures, StructureKernel, design_kernel
from adservice.representation import build_representation, search_structure

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
TKW: dict[str, Any] = {"dtype": torch.float64}
FAST = {"raw_samples": 256, "num_restarts": 4, "maxiter": 30}
"""Smaller acquisition searches for the tests that check what a proposal or a fit is,
not how good the proposal is (the default: 2048 raw samples, 10 restarts, 100
iterations)."""


def example(name: str) -> tuple[DesignSpace, Representation, SearchStructure]:
    body = StudyCreate.model_validate(yaml.safe_load((EXAMPLES / f"{name}.yaml").read_text()))
    assert isinstance(body.space, DesignSpace)
    representation = build_representation(body.space)
    search = search_structure(body.space, representation)
    assert search is not None
    return body.space, representation, search


@pytest.fixture(scope="module")
def multi() -> tuple[DesignSpace, Representation, SearchStructure]:
    return example("multi-structure")


def random_vectors(representation: Representation, count: int, seed: int) -> np.ndarray:
    low, high = np.asarray(representation.bounds)
    return low + np.random.default_rng(seed).random((count, len(low))) * (high - low)


def design_request(
    representation: Representation,
    search: SearchStructure,
    X: np.ndarray,
    y: np.ndarray,
    **extra: Any,
) -> ProposalRequest:
    bounds = np.asarray(representation.bounds)
    dim = bounds.shape[1]
    return ProposalRequest(
        bounds=bounds,
        count=extra.pop("count", 1),
        seed=extra.pop("seed", 0),
        n_issued=len(X),
        X=X,
        y=y,
        failed=empty_history(dim),
        pending=extra.pop("pending", empty_history(dim)),
        structure=search,
        **extra,
    )


# -- the structure kernel -----------------------------------------------------------------


def test_structure_kernel_runs_from_one_hot_to_all_alike(multi: Any) -> None:
    """Its two limits: a tiny length scale makes every structure unrelated (the one-hot
    encoding's identity matrix), a huge one makes them all alike."""
    _, _, search = multi
    kernel = StructureKernel(torch.as_tensor(search.structure_coords, **TKW)).to(**TKW)
    index = torch.arange(search.n_structures, **TKW).unsqueeze(-1)
    z = torch.cat([index, torch.zeros(len(index), 3, **TKW)], dim=-1)
    kernel.lengthscale = torch.tensor(1e-3, **TKW)
    with torch.no_grad():
        unrelated = kernel(z, z).to_dense()
    np.testing.assert_allclose(unrelated.numpy(), np.eye(search.n_structures), atol=1e-12)
    kernel.lengthscale = torch.tensor(1e4, **TKW)
    with torch.no_grad():
        alike = kernel(z, z).to_dense()
    np.testing.assert_allclose(alike.numpy(), 1.0, atol=1e-6)
    kernel.lengthscale = torch.tensor(0.5, **TKW)
    with torch.no_grad():
        between = kernel(z, z).to_dense().numpy()
    off = between[~np.eye(search.n_structures, dtype=bool)]
    assert off.min() > 0.0 and off.max() < 1.0
    assert np.all(np.linalg.eigvalsh(between) > -1e-10)  # a valid covariance


def fitted(
    search: SearchStructure, representation: Representation, y_of: Any, seed: int
) -> dict[str, Any]:
    X = random_vectors(representation, 48, seed)
    Z = model_inputs(X, np.asarray(representation.bounds), search)
    y = np.array([y_of(z) for z in Z])
    proposal = get_proposer("qei").propose(
        design_request(
            representation, search, X, y, seed=seed, options={**FAST, "warm_start": False}
        )
    )
    return proposal.info[0]


def test_the_fitted_model_relates_structures_as_the_data_does(multi: Any) -> None:
    """Unrelated per-structure functions fit a structure length scale below the distance
    between structures (near one-hot) and a low correlation between structures; a
    function blind to the structure fits a correlation near 1."""
    _, representation, search = multi
    rng = np.random.default_rng(5)
    offsets = rng.normal(0.0, 1.0, size=search.n_structures)
    phases = rng.uniform(0, 2 * math.pi, size=(search.n_structures, search.spec_dim))

    def unrelated(z: np.ndarray) -> float:
        s = int(z[0])
        return float(offsets[s] + np.sin(3 * z[1:] + phases[s]).sum() / 3)

    def blind(z: np.ndarray) -> float:
        return float(np.sin(3 * z[1] + 1.0) + z[2])

    apart = fitted(search, representation, unrelated, seed=1)
    alike = fitted(search, representation, blind, seed=1)
    distances = np.linalg.norm(
        search.structure_coords[:, None] - search.structure_coords[None], axis=-1
    )
    nearest = distances[~np.eye(search.n_structures, dtype=bool)].min()
    assert apart["structure_lengthscale"] < nearest, (apart, nearest)
    assert apart["structure_correlation"] < 0.3, apart
    assert alike["structure_correlation"] > 0.6, alike


def test_one_structure_has_a_spec_kernel_alone_and_several_a_weighted_sum() -> None:
    _, _, search = example("stand-up")
    single = design_kernel(search, search.spec_dim, kernel="rbf", **TKW)
    assert single.structure is None
    assert design_kernel(None, 3, kernel="matern", **TKW).structure is None
    _, _, multi_search = example("multi-structure")
    kernel = design_kernel(multi_search, multi_search.spec_dim, kernel="rbf", **TKW)
    assert kernel.structure is not None
    # the sum a Ks + b Kx + c Ks Kx, each part from the kernels themselves
    z = torch.as_tensor(
        np.column_stack(
            [np.arange(6) % 6, np.random.default_rng(0).random((6, multi_search.spec_dim))]
        ),
        **TKW,
    )
    kernel.weights = torch.tensor([0.2, 0.3, 0.5], **TKW)
    with torch.no_grad():
        Ks = kernel.structure(z, z).to_dense()
        Kx = kernel.spec(z, z).to_dense()
        K = kernel(z, z).to_dense()
    torch.testing.assert_close(K, 0.2 * Ks + 0.3 * Kx + 0.5 * Ks * Kx)


# -- joint axes -------------------------------------------------------------------------


def axis_search(sign_invariant: bool) -> SearchStructure:
    return SearchStructure(
        structure_coords=np.zeros((1, 1)),
        used=np.ones((1, 2), dtype=bool),
        spec_low=np.array([0.0, 0.0]),
        spec_high=np.array([math.pi, 2 * math.pi]),
        axes=(AxisColumns(theta=0, phi=1, sign_invariant=sign_invariant),),
    )


def features(search: SearchStructure, theta: float, phi: float) -> np.ndarray:
    u = torch.tensor([[theta / math.pi, phi / (2 * math.pi)]], **TKW)
    return SpecFeatures(search, 2, **TKW)(u).numpy()[0]


@pytest.mark.parametrize("sign_invariant", [False, True])
def test_axis_features_have_no_pole_and_no_wrap_around(sign_invariant: bool) -> None:
    search = axis_search(sign_invariant)
    # every phi names the same axis at the pole, and phi = 0 and 2 pi are one axis
    np.testing.assert_allclose(features(search, 0.0, 0.3), features(search, 0.0, 5.0), atol=1e-12)
    np.testing.assert_allclose(
        features(search, 1.0, 0.0), features(search, 1.0, 2 * math.pi), atol=1e-12
    )
    # the features of perpendicular axes are as far apart as features can be: 1
    far = np.linalg.norm(features(search, math.pi / 2, 0.0) - features(search, 0.0, 0.0))
    expected = 1.0 if sign_invariant else math.sqrt(2) / 2
    assert far == pytest.approx(expected)


def test_sign_invariant_axes_see_an_axis_and_its_opposite_as_one() -> None:
    theta, phi = 0.7, 1.1
    opposite = (math.pi - theta, phi + math.pi)
    line = axis_search(True)
    np.testing.assert_allclose(features(line, theta, phi), features(line, *opposite), atol=1e-12)
    arrow = axis_search(False)
    assert np.linalg.norm(features(arrow, theta, phi) - features(arrow, *opposite)) > 0.9


@pytest.mark.parametrize("log", [False, True])
def test_axis_features_are_the_decoded_axis_on_a_log_scale_too(log: bool) -> None:
    """The model turns an axis's normalised slots into the axis the decoder builds,
    whether its angles are searched linearly or on a log scale."""
    space = DesignSpace.model_validate(
        {
            "type": "design",
            "parts": {"link": {"length": 0.4}},
            "joint": {
                "axis_theta": {"low": 0.05, "high": 3.0, "log": log},
                "axis_phi": {"low": 0.01, "high": 6.0, "log": log},
                "lower": -1.0,  # asymmetric limits: the axis is seen as an arrow
            },
            "instances": [{"name": "a", "part": "link"}, {"name": "b", "part": "link"}],
            "structures": [[["a", "b"]]],
        }
    )
    representation = build_representation(space)
    search = search_structure(space, representation)
    assert search is not None
    assert search.spec_log is None if not log else search.spec_log.tolist() == [True, True]
    for u in ([0.0, 0.0], [0.2, 0.7], [0.5, 0.5], [0.9, 0.1], [1.0, 1.0]):
        (joint,) = decode(space, representation, u).joints
        model = SpecFeatures(search, 2, **TKW)(torch.tensor([u], **TKW)).numpy()[0]
        np.testing.assert_allclose(model, np.asarray(joint.axis) / 2.0, atol=1e-12)


# -- the mixed acquisition ----------------------------------------------------------------


def check_candidates(
    space: DesignSpace, representation: Representation, search: SearchStructure, rows: np.ndarray
) -> None:
    """In the box, an integral structure index, unused slots at the pad, and decoded by
    identity: the design's specs are the vector's own (nothing clipped or invented)."""
    low, high = np.asarray(representation.bounds)
    layout = spec_layout(space)
    for row in rows:
        assert np.all(row >= low) and np.all(row <= high)
        assert row[0] == round(row[0])
        structure = int(row[0])
        used = search.used[structure]
        assert np.all(row[1:][~used] == PAD)
        design = decode(space, representation, row.tolist())
        assert design.structure_index == structure
        links = {link.name: link for link in design.links}
        joints = {joint.child: joint for joint in design.joints}
        for k, key in enumerate(layout.names):
            if not used[k]:
                continue
            name, _, spec = key.partition(".")
            value = (
                getattr(joints[name], spec.removeprefix("joint."))
                if spec.startswith("joint.")
                else getattr(links[name], spec)
            )
            assert value == pytest.approx(layout.denormalise(row[1:])[k], abs=1e-12)


@pytest.mark.parametrize("noisy", [False, True])
def test_mixed_batches_are_valid_distinct_designs(multi: Any, noisy: bool) -> None:
    space, representation, search = multi
    X = random_vectors(representation, 10, seed=3)
    y = np.random.default_rng(3).random(10)
    proposal = get_proposer("qei").propose(
        design_request(representation, search, X, y, count=4, noisy=noisy, options=FAST)
    )
    assert [entry["method"] for entry in proposal.info] == ["LogEI"] + ["LogEI-believer"] * 3
    check_candidates(space, representation, search, proposal.candidates)
    Z = model_inputs(proposal.candidates, np.asarray(representation.bounds), search)
    gaps = [np.abs(Z[i] - Z[j]).max() for i in range(4) for j in range(i + 1, 4)]
    assert min(gaps) > 1e-3


def test_mixed_acquisition_finds_the_structure_the_data_favours(multi: Any) -> None:
    """Structure 3 scores 1 everywhere, the others 0: the next design is of structure 3,
    even though it holds 1/6 of the raw samples."""
    space, representation, search = multi
    X = random_vectors(representation, 18, seed=4)
    Z = model_inputs(X, np.asarray(representation.bounds), search)
    y = (Z[:, 0] == 3).astype(float) + 0.01 * np.random.default_rng(4).random(18)
    if not (Z[:, 0] == 3).any():
        pytest.fail("the seed's history has no design of structure 3")
    proposal = get_proposer("qei").propose(design_request(representation, search, X, y))
    check_candidates(space, representation, search, proposal.candidates)
    assert int(proposal.candidates[0, 0]) == 3


def test_many_structures_are_searched_by_alternating_steps() -> None:
    """125 trees (more than are enumerated): the proposal is still a valid design."""
    body: dict[str, Any] = {
        "type": "design",
        "parts": {"link": {"length": {"low": 0.2, "high": 0.5}}},
        "instances": [{"name": n, "part": "link"} for n in "abcde"],
        "structures": "all",
        "max_structures": 125,
        "reference_per_structure": 2,
    }
    space = DesignSpace.model_validate(body)
    representation = build_representation(space)
    search = search_structure(space, representation)
    assert search is not None and search.n_structures == 125
    X = random_vectors(representation, 20, seed=6)
    y = np.random.default_rng(6).random(20)
    proposal = get_proposer("qei").propose(design_request(representation, search, X, y, count=2))
    check_candidates(space, representation, search, proposal.candidates)
    assert proposal.info[0]["num_restarts"] >= 1


# -- through the service ------------------------------------------------------------------


@pytest.fixture(scope="module")
def sqlite_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    workdir = tmp_path_factory.mktemp("design-model-server")
    server = ServerProcess(database_url=f"sqlite:///{workdir / 'studies.db'}", workdir=workdir)
    server.start()
    yield server
    server.stop()


@pytest.mark.e2e
def test_a_design_study_stores_designs_its_vectors_decode_to_exactly(
    sqlite_server: ServerProcess,
) -> None:
    body = yaml.safe_load((EXAMPLES / "multi-structure.yaml").read_text())
    body.pop("task")
    body["name"] = "mixed-e2e"
    space = DesignSpace.model_validate(body["space"])
    with httpx.Client(base_url=sqlite_server.url, timeout=120) as http:
        created = http.post("/api/v1/studies", json=body)
        assert created.status_code == 201, created.text
        study_id = created.json()["id"]
        stored = build_representation(space)  # deterministic: what the service stored
        assert stored.kind == "mixed"
        search = search_structure(space, stored)
        assert search is not None
        for round_number in range(3):
            asked = http.post(f"/api/v1/studies/{study_id}/ask", json={"count": 2})
            assert asked.status_code == 200, asked.text
            for trial in asked.json()["trials"]:
                vector = np.asarray(trial["vector"])
                check_candidates(space, stored, search, vector[None])  # Sobol points too
                design = decode(space, stored, trial["vector"])
                assert trial["params"]["structure_index"] == design.structure_index
                value = float(design.structure_index == 2) + 0.1 * round_number
                told = http.post(f"/api/v1/trials/{trial['id']}/tell", json={"value": value})
                assert told.status_code == 200, told.text


@pytest.mark.parametrize("noise", ["floor", "fixed"])
def test_fit_map_reaches_botorchs_optimum(multi: Any, noise: str) -> None:
    """The lean fit maximises the same posterior as BoTorch's fit_gpytorch_mll."""
    from botorch.fit import fit_gpytorch_mll
    from botorch.models import SingleTaskGP
    from botorch.models.transforms.outcome import Standardize
    from gpytorch.constraints import GreaterThan
    from gpytorch.likelihoods import GaussianLikelihood
    from gpytorch.mlls import ExactMarginalLogLikelihood

    from adservice.proposers.likelihood import fit_map

    _, representation, search = multi
    X = random_vectors(representation, 30, seed=2)
    Z = torch.as_tensor(model_inputs(X, np.asarray(representation.bounds), search), **TKW)
    y = torch.sin(3 * Z[:, 1:4].sum(-1, keepdim=True)) + 0.3 * (Z[:, :1] == 2)

    def model() -> SingleTaskGP:
        likelihood = (
            GaussianLikelihood(noise_constraint=GreaterThan(1e-6, transform=None))
            if noise == "floor"
            else None
        )
        return SingleTaskGP(
            Z,
            y,
            train_Yvar=None if noise == "floor" else torch.full_like(y, 1e-6),
            likelihood=likelihood,
            covar_module=design_kernel(search, search.spec_dim, kernel="matern", **TKW),
            outcome_transform=Standardize(m=1),
        ).to(**TKW)

    def log_posterior(fitted: SingleTaskGP) -> float:
        fitted.train()
        mll = ExactMarginalLogLikelihood(fitted.likelihood, fitted)
        with torch.no_grad():
            value = mll(fitted(Z), fitted.train_targets)
            for _, module, prior, closure, _ in fitted.named_priors():
                value = value + prior.log_prob(closure(module)).sum() / len(y)
        return float(value)

    ours, theirs = model(), model()
    fit_map(ours)
    fit_gpytorch_mll(ExactMarginalLogLikelihood(theirs.likelihood, theirs))
    assert log_posterior(ours) == pytest.approx(log_posterior(theirs), abs=1e-3)
