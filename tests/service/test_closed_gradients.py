"""The closed-form gradients of qei's hot loops equal autograd's: LogEI's with respect to
the model inputs (``Posterior.log_ei_with_gradient``, through the structure kernel, the
spec kernel and every kind of spec feature: plain, axes with and without sign, on a log
scale, categories), with and without pending points believed; and the fit's log
posterior's with respect to every hyperparameter (``likelihood.LogPosterior``), in each
noise mode. Their NumPy forms on the CPU (``arrays.ArrayPosterior`` through
``LogEI.on_arrays``, ``likelihood.ArrayLogPosterior``) equal the torch forms, and a
seeded search through them finds the torch path's candidate."""

from __future__ import annotations

import functools
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
import yaml

from adclient.boxspace import BoxEncoding
from adclient.design import DesignSpace
from adclient.schemas import StudyCreate
from adservice.proposers.base import ProposalRequest, empty_history, model_inputs
from adservice.proposers.gpfit import fit_outcome
from adservice.proposers.posterior import LogEI, Posterior
from adservice.proposers.qei_shared import QEIOptions
from adservice.representation import build_representation, search_structure

pytestmark = pytest.mark.xdist_group("closed-gradients")  # a fit shared by a case's variants

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
TKW: dict[str, Any] = {"dtype": torch.float64, "device": torch.device("cpu")}
LOG_AXES = {
    "type": "design",
    "parts": {"link": {"length": {"low": 0.1, "high": 0.5}}},
    "joint": {
        "axis_theta": {"low": 0.05, "high": 3.0, "log": True},
        "axis_phi": {"low": 0.01, "high": 6.0, "log": True},
        "lower": -1.0,
    },
    "instances": [{"name": "a", "part": "link"}, {"name": "b", "part": "link"}],
    "structures": [[["a", "b"]]],
}
TYPED_BOX = {
    "type": "box",
    "params": [
        {"name": "x", "low": -2.0, "high": 2.0},
        {"name": "width", "type": "int", "low": 1, "high": 64, "log": True},
        {"name": "activation", "type": "categorical", "choices": ["relu", "tanh", "gelu"]},
        {"name": "y", "low": 0.0, "high": 3.0},
    ],
}


def request_for(case: str, n: int, seed: int) -> ProposalRequest:
    """n random observations of a smooth function in one of the spaces."""
    box = None
    search = None
    if case == "typed-box":
        box = BoxEncoding.of(TYPED_BOX)
        bounds = box.bounds
    elif case == "box":
        bounds = np.array([[-1.0, 0.0, -3.0], [1.0, 2.0, 3.0]])
    else:
        if case == "log-axes":
            space = DesignSpace.model_validate(LOG_AXES)
        else:
            body = yaml.safe_load((EXAMPLES / f"{case}.yaml").read_text())
            parsed = StudyCreate.model_validate(body).space
            assert isinstance(parsed, DesignSpace)
            space = parsed
        representation = build_representation(space)
        search = search_structure(space, representation)
        bounds = np.asarray(representation.bounds)
    rng = np.random.default_rng(seed)
    dim = bounds.shape[1]
    X = bounds[0] + rng.random((n, dim)) * (bounds[1] - bounds[0])
    if box is not None:
        X = box.snap(X)
    y = np.sin(3.0 * model_inputs(X, bounds, search)).sum(axis=1) + 0.1 * rng.random(n)
    return ProposalRequest(
        bounds=bounds,
        count=1,
        seed=seed,
        n_issued=n,
        X=X,
        y=y,
        failed=empty_history(dim),
        pending=empty_history(dim),
        structure=search,
        box=box,
    )


CASES = ["box", "typed-box", "multi-structure", "joint-kinds", "log-axes"]


def fitted(request: ProposalRequest, **options: Any) -> Any:
    """The request's GP, fitted cold."""
    qei = QEIOptions(warm_start=False, **options)
    return fit_outcome(request, qei, request.bounds, request.X, request.y, TKW, None)[0]


@functools.cache
def fitted_once(case: str, n: int, seed: int, kernel: str) -> Any:
    """:func:`fitted` of ``request_for(case, n, seed)`` with ``kernel``, fitted once per
    test process for the acquisition tests, with and without believed points, that only
    read it (a ``Posterior`` of it copies what it needs)."""
    return fitted(request_for(case, n, seed), kernel=kernel)


def every_acquisition_case(test: Any) -> Any:
    """Each space, kernel, and with and without believed pending points."""
    for mark in (
        pytest.mark.parametrize("case", CASES),
        pytest.mark.parametrize("kernel", ["matern", "rbf"]),
        pytest.mark.parametrize("believing", [False, True]),
    ):
        test = mark(test)
    return test


@every_acquisition_case
def test_log_ei_gradient_is_autograds(case: str, kernel: str, believing: bool) -> None:
    request = request_for(case, 16, seed=3)
    model = fitted_once(case, 16, 3, kernel)
    posterior = Posterior(model)
    probe = request_for(case, 9, seed=4)
    points = torch.as_tensor(model_inputs(probe.X, request.bounds, request.structure), **TKW)
    if believing:
        posterior = posterior.believing(points[:2])
        points = points[2:]
    acquisition = LogEI(posterior, float(request.y.max()) + 0.05)
    # one probe at an observed point: its variance at the floor, its gradient still right
    points = torch.cat(
        [
            points,
            torch.as_tensor(model_inputs(request.X[:1], request.bounds, request.structure), **TKW),
        ]
    )
    tracked = points.clone().requires_grad_(True)
    expected_values = acquisition(tracked.unsqueeze(1))
    (expected,) = torch.autograd.grad(expected_values.sum(), tracked)
    values, gradient = acquisition.value_and_grad(points)
    # at the observed point the variance is a difference of nearly equal numbers
    torch.testing.assert_close(values, expected_values.detach(), rtol=1e-8, atol=1e-10)
    scale = float(expected.abs().max())
    assert scale > 0.0 and math.isfinite(scale)
    torch.testing.assert_close(gradient, expected, rtol=1e-7, atol=1e-9 * scale)


def reference_log_posterior(model: Any) -> torch.Tensor:
    """The fit's log posterior by autograd through gpytorch's own kernel call."""
    train = model.train_inputs[0]
    noise = model.likelihood.noise.reshape(-1)
    K = model.covar_module(train, train).to_dense()
    K = K + torch.diag(noise.expand(len(train)))
    factor = torch.linalg.cholesky(K)
    residual = model.train_targets - model.mean_module.constant
    alpha = torch.cholesky_solve(residual.unsqueeze(-1), factor).squeeze(-1)
    value = -0.5 * (residual * alpha).sum() - torch.log(torch.diagonal(factor)).sum()
    for _, module, prior, closure, _ in model.named_priors():
        value = value + prior.log_prob(closure(module)).sum()
    return value


@pytest.mark.parametrize("case", ["box", "typed-box", "multi-structure", "joint-kinds"])
@pytest.mark.parametrize("noise", ["floor", "inferred", "fixed"])
def test_log_posterior_gradient_is_autograds(case: str, noise: str) -> None:
    from adservice.proposers.likelihood import LogPosterior

    request = request_for(case, 14, seed=5)
    model = fitted(request, noise=noise, kernel="matern" if case != "box" else "rbf")
    model.train()
    parameters = [p for p in model.parameters() if p.requires_grad]
    with torch.no_grad():  # away from the optimum, where every gradient is 0
        for number, parameter in enumerate(parameters):
            parameter.mul_(1.0 + 0.1 * (number % 3 + 1))
    expected_value = reference_log_posterior(model)
    expected = torch.autograd.grad(expected_value, parameters, allow_unused=True)
    found = LogPosterior(model)()
    assert found is not None
    value, gradients = found
    assert value == pytest.approx(float(expected_value), rel=1e-10, abs=1e-10)
    assert len(parameters) >= 2
    for parameter, theirs in zip(parameters, expected, strict=True):
        assert theirs is not None
        torch.testing.assert_close(gradients[id(parameter)], theirs, rtol=1e-7, atol=1e-8)


class TorchOnly:
    """An acquisition's torch interfaces alone: ``maximise`` searches it as it searches
    one without arrays (a GPU posterior's)."""

    def __init__(self, acquisition: LogEI) -> None:
        self.acquisition = acquisition

    def __call__(self, Z: torch.Tensor) -> torch.Tensor:
        return self.acquisition(Z)

    def value_and_grad(self, X: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.acquisition.value_and_grad(X)


@every_acquisition_case
def test_log_ei_on_arrays_is_the_torch_paths(case: str, kernel: str, believing: bool) -> None:
    request = request_for(case, 16, seed=6)
    model = fitted_once(case, 16, 6, kernel)
    posterior = Posterior(model)
    probe = request_for(case, 12, seed=7)
    points = model_inputs(probe.X, request.bounds, request.structure)
    if believing:
        posterior = posterior.believing(torch.as_tensor(points[:2], **TKW))
        points = points[2:]
    acquisition = LogEI(posterior, float(request.y.max()) + 0.05)
    assert acquisition.on_arrays is not None
    tensor = torch.as_tensor(points, **TKW)
    expected_values, expected = acquisition.value_and_grad(tensor)
    values, gradient = acquisition.on_arrays.with_gradient(points)
    scale = float(expected.abs().max())
    assert scale > 0.0 and math.isfinite(scale)
    np.testing.assert_allclose(values, expected_values.numpy(), rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(gradient, expected.numpy(), rtol=1e-6, atol=1e-8 * scale)
    with torch.no_grad():
        plain = acquisition(tensor.unsqueeze(1)).numpy()
    np.testing.assert_allclose(acquisition.on_arrays.values(points), plain, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("case", ["multi-structure", "joint-kinds", "typed-box"])
def test_a_seeded_search_on_arrays_finds_the_torch_paths_candidate(case: str) -> None:
    from adservice.proposers.acquisition import maximise
    from adservice.proposers.greedy import Greedy

    request = request_for(case, 20, seed=8)
    model = fitted(request)
    Z = model_inputs(request.X, request.bounds, request.structure)
    acquisition = LogEI(Posterior(model), float(request.y.max()))
    greedy = Greedy.of(
        request,
        QEIOptions(),
        request.bounds,
        Z,
        request.pending,
        Z[np.argsort(-request.y)],
        TKW,
        None,
    )
    found = [
        maximise(
            searched,
            greedy.domain,
            raw_count=512,
            num_restarts=greedy.num_restarts,
            maxiter=greedy.maxiter,
            seed=11,
            incumbents=greedy.incumbents,
            tkw=TKW,
            taken=greedy.taken,
        )
        for searched in (acquisition, TorchOnly(acquisition))
    ]
    # the same structure and acquisition value; the specs as close as the local searches'
    # stop (LOCAL_GTOL) allows: rounding can move a start's last step by a few 1e-5
    assert found[0].z[0] == found[1].z[0]
    np.testing.assert_allclose(found[0].z, found[1].z, atol=1e-4)
    assert found[0].value == pytest.approx(found[1].value, abs=1e-6)


@pytest.mark.parametrize("case", ["box", "typed-box", "multi-structure", "joint-kinds"])
@pytest.mark.parametrize("noise", ["floor", "inferred", "fixed"])
def test_log_posterior_on_arrays_is_the_torch_paths(case: str, noise: str) -> None:
    from botorch.optim.utils import get_parameters_and_bounds

    from adservice.proposers.likelihood import ArrayLogPosterior, LogPosterior

    model = fitted(request_for(case, 14, seed=9), noise=noise)
    model.train()
    tensors = list(get_parameters_and_bounds(model, requires_grad=True)[0].values())
    with torch.no_grad():  # away from the optimum, where every gradient is 0
        for number, parameter in enumerate(tensors):
            parameter.mul_(1.0 - 0.1 * (number % 3 + 1))
    found = LogPosterior(model)()
    assert found is not None
    expected_value, by_tensor = found
    expected = torch.cat(
        [by_tensor.get(id(t), torch.zeros_like(t)).reshape(-1) for t in tensors]
    ).numpy()
    flat = np.concatenate([t.detach().reshape(-1).numpy() for t in tensors])
    on_arrays = ArrayLogPosterior(LogPosterior(model), tensors)(flat)
    assert on_arrays is not None
    value, gradient = on_arrays
    # inferred noise shrunk to near its floor: K's log determinant agrees to ~1e-8 only
    assert value == pytest.approx(expected_value, rel=1e-7)
    assert np.abs(expected).max() > 0.0
    np.testing.assert_allclose(gradient, expected, rtol=1e-6, atol=1e-8 * np.abs(expected).max())


def test_a_posteriors_arrays_do_not_change_with_its_tensors() -> None:
    """``ArrayPosterior`` holds copies: a posterior's tensors changed in place after its
    arrays were made (here its weights of the observations and its embedded training
    points) leave the NumPy path's values as they were."""
    request = request_for("multi-structure", 16, seed=6)
    posterior = Posterior(fitted(request))
    acquisition = LogEI(posterior, float(request.y.max()) + 0.05)
    assert acquisition.on_arrays is not None
    points = model_inputs(
        request_for("multi-structure", 12, seed=7).X, request.bounds, request.structure
    )
    before = acquisition.on_arrays.values(points)
    with torch.no_grad():
        posterior.alpha.mul_(3.0)
        posterior.embedded[0].add_(0.5)
    np.testing.assert_array_equal(acquisition.on_arrays.values(points), before)
