"""Fitting a qei GP's hyperparameters: maximum a posteriori, the log marginal likelihood
and its gradient in closed form (``LogPosterior``), L-BFGS-B over the raw parameters
(``fit_map``), in NumPy for a model on the CPU (``ArrayLogPosterior``).

Imported only when a proposal is computed (it imports torch and gpytorch).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import torch
from gpytorch.priors import LogNormalPrior
from scipy.linalg import cho_solve, solve_triangular

from adservice.proposers.acquisition import OutOfTime, past
from adservice.proposers.arrays import with_slope
from adservice.proposers.gpmodel import DesignKernel

FIT_GTOL = 1e-2
"""The fit stops when no gradient of the log posterior (summed over the observations)
exceeds this: Optuna's GPSampler's tolerance. BoTorch's scipy default (1e-5 here on the
mean per observation) cost 100 to 220 likelihood evaluations a fit on the 8-tree suite
space at n = 30, with the same candidates."""


class LogPosterior:
    """A ``SingleTaskGP``'s log marginal likelihood (without its constant) plus its
    hyperparameters' log priors, at their current values, and its gradient with
    respect to each raw parameter, in closed form: the likelihood's by the identity
    d/dK = (alpha alpha^T - K^-1) / 2 carried through the ``DesignKernel`` by hand (its
    weights, the structure length scale, each spec length-scale group, the noise and
    the mean), each log-normal prior's written out. No autograd: its backward pass
    through the covariance matrix cost twice the forward one, a hundred times a fit.

    Every parameter must be its own value (its constraint's ``transform=None``, the
    bounds kept by the optimiser), which the models of ``gpfit`` are, and every prior
    log-normal; anything else is a TypeError. What no hyperparameter changes is
    computed once: each spec group's squared distances between the training points
    (n x n x groups) and the structures'."""

    def __init__(self, model: Any) -> None:
        self.model = model
        kernel: DesignKernel = model.covar_module
        self.kernel = kernel
        self.targets = model.train_targets
        for name, constraint in model.named_constraints():
            if constraint.enforced:
                raise TypeError(f"{name} transforms its parameter: LogPosterior needs none")
        self.parameters = {id(p) for p in model.parameters() if p.requires_grad}
        self.priors = []
        for name, module, prior, closure, _ in model.named_priors():
            if type(prior) is not LogNormalPrior or getattr(prior, "_transform", None):
                raise TypeError(f"{name}: LogPosterior writes out log-normal priors only")
            self.priors.append((module, prior, closure))
        train = model.train_inputs[0]
        with torch.no_grad():
            features = kernel.spec.inputs(train)
            gaps = (features[:, None, :] - features[None, :, :]) ** 2
            self.spec_parts = torch.zeros(
                (*gaps.shape[:2], kernel.spec.features.n_groups),
                dtype=gaps.dtype,
                device=gaps.device,
            ).index_add_(-1, kernel.spec.features.group_index, gaps)
            self.structure_squared = None
            if kernel.structure is not None:
                coords = kernel.structure.inputs(train)
                self.structure_squared = ((coords[:, None, :] - coords[None, :, :]) ** 2).sum(-1)

    @torch.no_grad()
    def __call__(self) -> tuple[float, dict[int, torch.Tensor]] | None:
        """The log posterior and its gradient by parameter (keyed by ``id``; one that
        nothing depends on is absent); None where the covariance is not positive
        definite."""
        model, kernel = self.model, self.kernel
        spec, structure = kernel.spec, kernel.structure
        lengthscale = spec.lengthscale
        scales = lengthscale.reshape(-1)
        noise = model.likelihood.noise
        constant = model.mean_module.constant
        squared = self.spec_parts @ scales.pow(-2)
        spec_k, spec_slope = spec.with_slope(squared)
        if structure is None:
            K = spec_k.clone()
        else:
            assert self.structure_squared is not None
            structure_scale = structure.lengthscale
            structure_k = torch.exp(
                -0.5 * self.structure_squared / structure_scale.reshape(()) ** 2
            )
            weights = kernel.weights
            a, b, c = weights
            K = a * structure_k + (b + c * structure_k) * spec_k
        K.diagonal().add_(noise.reshape(-1).expand(len(K)))
        factor, info = torch.linalg.cholesky_ex(K)
        if int(info) != 0:
            return None
        residual = self.targets - constant.reshape(())
        alpha = torch.cholesky_solve(residual.unsqueeze(-1), factor).squeeze(-1)
        value = -0.5 * (residual * alpha).sum() - torch.log(torch.diagonal(factor)).sum()
        # d value / dK
        half = 0.5 * (alpha[:, None] * alpha[None, :] - torch.cholesky_inverse(factor))
        gradients: dict[int, torch.Tensor] = {}

        def add(parameter: torch.Tensor, gradient: torch.Tensor) -> None:
            if id(parameter) in self.parameters:
                gradient = gradient.reshape(parameter.shape)
                known = gradients.get(id(parameter))
                gradients[id(parameter)] = gradient if known is None else known + gradient

        per_spec = half
        if structure is not None:
            per_spec = half * (b + c * structure_k)
            per_structure = half * (a + c * spec_k) * structure_k * self.structure_squared
            add(structure_scale, per_structure.sum() / structure_scale**3)
            per_weight = [
                (half * structure_k).sum(),
                (half * spec_k).sum(),
                (half * structure_k * spec_k).sum(),
            ]
            add(weights, torch.stack(per_weight))
        per_squared = per_spec * spec_slope
        add(lengthscale, -2.0 * torch.einsum("ij,ijg->g", per_squared, self.spec_parts) / scales**3)
        diagonal = half.diagonal()
        add(noise, diagonal.sum() if noise.numel() == 1 else diagonal)
        add(constant, alpha.sum())
        for module, prior, closure in self.priors:
            at = closure(module)
            logged = torch.log(at)
            spread = prior.scale**2
            value = (
                value
                + (
                    -((logged - prior.loc) ** 2) / (2.0 * spread)
                    - torch.log(prior.scale)
                    - 0.5 * math.log(2.0 * math.pi)
                    - logged
                ).sum()
            )
            add(at, -((logged - prior.loc) / spread + 1.0) / at)
        return float(value), gradients


Role = tuple[tuple[int, int] | None, np.ndarray]
"""Where a hyperparameter lies in the fit's flat vector (offset, size), or None for a
constant, and its value when it is a constant."""


class ArrayLogPosterior:
    """``LogPosterior`` in NumPy on the fit's flat parameter vector (the order of
    ``tensors``), for a model on the CPU in float64: the same value and gradient within
    rounding (tested), without a tensor operation's dispatch each, and without copying
    the vector into the model's parameters at every evaluation."""

    def __init__(self, log_posterior: LogPosterior, tensors: list[torch.Tensor]) -> None:
        offsets, at = {}, 0
        for tensor in tensors:
            offsets[id(tensor)] = (at, tensor.numel())
            at += tensor.numel()
        self.size = at

        def role(tensor: torch.Tensor) -> Role:
            return offsets.get(id(tensor)), tensor.detach().numpy().reshape(-1).copy()

        model, kernel = log_posterior.model, log_posterior.kernel
        self.targets = log_posterior.targets.detach().numpy()
        count = len(self.targets)
        self.spec_parts = log_posterior.spec_parts.numpy().reshape(count * count, -1)
        self.rbf = kernel.spec.rbf
        self.lengthscale = role(kernel.spec.lengthscale)
        self.noise = role(model.likelihood.noise)
        self.constant = role(model.mean_module.constant)
        self.structure: tuple[np.ndarray, Role, Role] | None = None
        if kernel.structure is not None:
            assert log_posterior.structure_squared is not None
            self.structure = (
                log_posterior.structure_squared.numpy(),
                role(kernel.structure.lengthscale),
                role(kernel.weights),
            )
        self.priors = [
            (role(closure(module)), float(prior.loc), float(prior.scale))
            for module, prior, closure in log_posterior.priors
        ]

    def __call__(self, flat: np.ndarray) -> tuple[float, np.ndarray] | None:
        """The log posterior at ``flat`` and its gradient (flat); None where the
        covariance is not positive definite."""

        def value_of(role: Role) -> np.ndarray:
            where, fixed = role
            return fixed if where is None else flat[where[0] : where[0] + where[1]]

        gradient = np.zeros(self.size)

        def add(role: Role, slope: np.ndarray | float) -> None:
            where = role[0]
            if where is not None:
                gradient[where[0] : where[0] + where[1]] += np.reshape(slope, -1)

        count = len(self.targets)
        scales = value_of(self.lengthscale)
        squared = (self.spec_parts @ scales**-2).reshape(count, count)
        spec_k, spec_slope = with_slope(squared, rbf=self.rbf)
        if self.structure is None:
            K = spec_k.copy()
        else:
            structure_squared, structure_scale, weights = self.structure
            length = float(value_of(structure_scale)[0])
            structure_k = np.exp(-0.5 * structure_squared / length**2)
            a, b, c = value_of(weights)
            K = a * structure_k + (b + c * structure_k) * spec_k
        noise = value_of(self.noise)
        K[np.diag_indices(count)] += noise
        try:
            factor = np.linalg.cholesky(K)
        except np.linalg.LinAlgError:
            return None
        inverse_factor = solve_triangular(factor, np.eye(count), lower=True, check_finite=False)
        inverse = inverse_factor.T @ inverse_factor
        residual = self.targets - value_of(self.constant)[0]
        alpha = cho_solve((factor, True), residual, check_finite=False)
        value = -0.5 * residual @ alpha - np.log(np.diagonal(factor)).sum()
        half = 0.5 * (np.outer(alpha, alpha) - inverse)
        per_spec = half
        if self.structure is not None:
            per_spec = half * (b + c * structure_k)
            per_structure = half * (a + c * spec_k) * structure_k * structure_squared
            add(structure_scale, per_structure.sum() / length**3)
            per_weight = [
                (half * structure_k).sum(),
                (half * spec_k).sum(),
                (half * structure_k * spec_k).sum(),
            ]
            add(weights, np.array(per_weight))
        per_squared = (per_spec * spec_slope).reshape(-1)
        add(self.lengthscale, -2.0 * (per_squared @ self.spec_parts) / scales**3)
        diagonal = np.diagonal(half)
        add(self.noise, diagonal.sum() if noise.size == 1 else diagonal)
        add(self.constant, alpha.sum())
        for prior_role, loc, scale in self.priors:
            at = value_of(prior_role)
            logged = np.log(at)
            spread = scale**2
            value += (
                -((logged - loc) ** 2) / (2.0 * spread)
                - math.log(scale)
                - 0.5 * math.log(2.0 * math.pi)
                - logged
            ).sum()
            add(prior_role, -((logged - loc) / spread + 1.0) / at)
        return float(value), gradient


def fit_map(model: Any, *, maxiter: int = 200, deadline: float | None = None) -> int:
    """Fit the hyperparameters by maximum a posteriori marginal likelihood, as BoTorch's
    ``fit_gpytorch_mll`` does (L-BFGS-B on the raw parameters, within their
    constraints' bounds, from their current values), with the log posterior and its
    gradient from ``LogPosterior``, without gpytorch's lazy kernel and distribution
    objects, which cost more than the arithmetic at small n (bench/RESULTS.md). Same
    optimum (tested). Past ``deadline`` (``time.monotonic()``) it
    stops with the best parameters evaluated so far (the ask's time budget).
    Returns the number of likelihood evaluations."""
    from botorch.optim.utils import get_parameters_and_bounds
    from scipy.optimize import minimize

    params, bounds = get_parameters_and_bounds(model, requires_grad=True)
    tensors = list(params.values())
    limits = [bounds.get(name, (None, None)) for name in params]
    low = np.concatenate(
        [
            np.full(tensor.numel(), -np.inf if lo is None else float(lo))
            for tensor, (lo, _) in zip(tensors, limits, strict=True)
        ]
    )
    high = np.concatenate(
        [
            np.full(tensor.numel(), np.inf if hi is None else float(hi))
            for tensor, (_, hi) in zip(tensors, limits, strict=True)
        ]
    )
    log_posterior = LogPosterior(model)
    on_arrays = None
    train = model.train_inputs[0]
    if train.device.type == "cpu" and train.dtype == torch.float64:
        on_arrays = ArrayLogPosterior(log_posterior, tensors)
    count = len(model.train_targets)
    evaluations = 0
    best: tuple[float, np.ndarray | None] = (math.inf, None)

    def load(flat: np.ndarray) -> None:
        offset = 0
        with torch.no_grad():
            for tensor in tensors:
                size = tensor.numel()
                tensor.copy_(torch.as_tensor(flat[offset : offset + size]).reshape(tensor.shape))
                offset += size

    def objective(flat: np.ndarray) -> tuple[float, np.ndarray]:
        nonlocal evaluations, best
        if evaluations and past(deadline):
            raise OutOfTime
        evaluations += 1
        if on_arrays is not None:
            found = on_arrays(flat)
        else:
            load(flat)
            found = by_tensor(log_posterior())
        if found is None or not math.isfinite(found[0]):
            return 1e10, np.zeros_like(flat)
        loss = -found[0] / count
        if loss < best[0]:
            best = (loss, flat.copy())
        return loss, found[1] / -count

    def by_tensor(
        found: tuple[float, dict[int, torch.Tensor]] | None,
    ) -> tuple[float, np.ndarray] | None:
        """``LogPosterior``'s gradient as one flat vector."""
        if found is None:
            return None
        gradient = [
            found[1].get(id(tensor), torch.zeros_like(tensor)).reshape(-1) for tensor in tensors
        ]
        return found[0], torch.cat(gradient).cpu().numpy().astype(np.float64)

    start = np.concatenate([tensor.detach().cpu().reshape(-1).numpy() for tensor in tensors])
    model.train()
    try:
        result = minimize(
            objective,
            np.clip(start, low, high),
            jac=True,
            method="L-BFGS-B",
            bounds=list(zip(low, high, strict=True)),
            # Optuna's GPSampler stops its fit at a gradient of 1e-2 of the (unscaled) log
            # posterior; this loss is that divided by n
            options={"maxiter": maxiter, "gtol": FIT_GTOL / count},
        )
        final = result.x
    except OutOfTime:
        final = best[1] if best[1] is not None else np.clip(start, low, high)
    load(final)
    return evaluations
