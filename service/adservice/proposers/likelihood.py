"""Fitting a qei GP's hyperparameters: maximum a posteriori, the log marginal likelihood
and its gradient in closed form (``LogPosterior``), L-BFGS-B over the raw parameters
(``fit_map``).

Imported only when a proposal is computed (it imports torch and gpytorch).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import torch
from gpytorch.priors import LogNormalPrior

from adservice.proposers.acquisition import OutOfTime, past
from adservice.proposers.gpmodel import DesignKernel

FIT_GTOL = 1e-2
"""The fit stops when no gradient of the log posterior (summed over the observations)
exceeds this: Optuna's GPSampler's tolerance. BoTorch's scipy default (1e-5 here on the
mean per observation) cost 100 to 220 likelihood evaluations a fit on the 8-tree suite
space at n = 30, with the same candidates."""


class LogPosterior:
    """A ``SingleTaskGP``'s log marginal likelihood (without its constant) plus its
    hyperparameters' log priors, at their current values, with a gradient that is
    exact: the likelihood's by the identity d/dK = (alpha alpha^T - K^-1) / 2 carried
    through the ``DesignKernel`` by hand (its weights, the structure length scale, each
    spec length-scale group, the noise and the mean), the priors' by autograd over a
    few scalars. Autograd through the covariance matrix cost twice the forward pass
    and ran a hundred times a fit.

    What no hyperparameter changes is computed once: each spec group's squared
    distances between the training points (n x n x groups) and the structures'."""

    def __init__(self, model: Any) -> None:
        self.model = model
        kernel: DesignKernel = model.covar_module
        self.kernel = kernel
        self.targets = model.train_targets
        self.priors = list(model.named_priors())
        train = model.train_inputs[0]
        with torch.no_grad():
            features = kernel.spec.inputs(train)
            gaps = (features[:, None, :] - features[None, :, :]) ** 2
            groups = kernel.spec.features.group_index.to(train.device)
            self.spec_parts = torch.zeros(
                (*gaps.shape[:2], kernel.spec.features.n_groups),
                dtype=gaps.dtype,
                device=gaps.device,
            ).index_add_(-1, groups, gaps)
            self.structure_squared = None
            if kernel.structure is not None:
                coords = kernel.structure.inputs(train)
                self.structure_squared = ((coords[:, None, :] - coords[None, :, :]) ** 2).sum(-1)

    def __call__(self) -> torch.Tensor | None:
        """The log posterior as a tensor whose ``backward`` gives the raw parameters'
        gradients; None where the covariance is not positive definite."""
        model, kernel = self.model, self.kernel
        spec, structure = kernel.spec, kernel.structure
        lengthscale = spec.lengthscale.reshape(-1)
        noise = model.likelihood.noise.reshape(-1)
        constant = model.mean_module.constant.reshape(())
        structure_scale = structure.lengthscale.reshape(()) if structure is not None else None
        weights = kernel.weights if structure is not None else None
        derived: list[tuple[torch.Tensor, torch.Tensor]] = []
        with torch.no_grad():
            squared = self.spec_parts @ lengthscale.pow(-2)
            spec_k, spec_slope = spec.with_slope(squared)
            structure_k = None
            if structure is None:
                K = spec_k.clone()
            else:
                assert self.structure_squared is not None
                assert structure_scale is not None and weights is not None
                structure_k = torch.exp(-0.5 * self.structure_squared / structure_scale**2)
                a, b, c = weights
                K = a * structure_k + (b + c * structure_k) * spec_k
            K.diagonal().add_(noise.expand(len(K)))
            factor, info = torch.linalg.cholesky_ex(K)
            if int(info) != 0:
                return None
            residual = self.targets - constant
            alpha = torch.cholesky_solve(residual.unsqueeze(-1), factor).squeeze(-1)
            log_likelihood = (
                -0.5 * (residual * alpha).sum() - torch.log(torch.diagonal(factor)).sum()
            )
            # d log_likelihood / dK
            half = 0.5 * (alpha[:, None] * alpha[None, :] - torch.cholesky_inverse(factor))
            per_spec = half
            if structure_k is not None:
                per_spec = half * (b + c * structure_k)
                per_structure = (
                    half * (a + c * spec_k) * structure_k * self.structure_squared
                ).sum()
                derived.append((structure_scale, per_structure / structure_scale**3))
                per_weight = [
                    (half * structure_k).sum(),
                    (half * spec_k).sum(),
                    (half * structure_k * spec_k).sum(),
                ]
                derived.append((weights, torch.stack(per_weight)))
            per_squared = per_spec * spec_slope
            per_scale = (
                -2.0 * torch.einsum("ij,ijg->g", per_squared, self.spec_parts) / lengthscale**3
            )
            derived.append((lengthscale, per_scale))
            diagonal = half.diagonal()
            derived.append((noise, diagonal.sum().reshape(1) if noise.numel() == 1 else diagonal))
            derived.append((constant, alpha.sum()))
        # the value is the log posterior; the gradient of each derived quantity is its own
        total = log_likelihood
        for quantity, gradient in derived:
            if quantity.requires_grad:
                total = total + (gradient * (quantity - quantity.detach())).sum()
        for _, module, prior, closure, _ in self.priors:
            total = total + log_prior(prior, closure(module)).sum()
        return total


def log_prior(prior: Any, value: torch.Tensor) -> torch.Tensor:
    """A prior's log density at ``value``: a log-normal's written out (torch's
    transformed distribution takes a dozen operations and a validation), others by
    their own ``log_prob``."""
    if type(prior) is LogNormalPrior and getattr(prior, "_transform", None) is None:
        logged = torch.log(value)
        scale = prior.scale
        return (
            -((logged - prior.loc) ** 2) / (2.0 * scale**2)
            - torch.log(scale)
            - 0.5 * math.log(2.0 * math.pi)
            - logged
        )
    return prior.log_prob(value)


def fit_map(model: Any, *, maxiter: int = 200, deadline: float | None = None) -> int:
    """Fit the hyperparameters by maximum a posteriori marginal likelihood, as BoTorch's
    ``fit_gpytorch_mll`` does (L-BFGS-B on the raw parameters, within their
    constraints' bounds, from their current values), with the log posterior and its
    gradient from ``LogPosterior``, without gpytorch's lazy kernel and distribution
    objects. Same optimum (tested); the
    median fit of ``bench/asklatency.py`` at n = 50, d = 6 fell from 0.087 s to
    0.069 s (bench/RESULTS.md). Past ``deadline`` (``time.monotonic()``) it
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
    log_posterior_of = LogPosterior(model)
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
        load(flat)
        for tensor in tensors:
            tensor.grad = None
        log_posterior = log_posterior_of()
        if log_posterior is None:
            return 1e10, np.zeros_like(flat)
        loss = -log_posterior / count
        if not torch.isfinite(loss):
            return 1e10, np.zeros_like(flat)
        loss.backward()
        if float(loss.detach()) < best[0]:
            best = (float(loss.detach()), flat.copy())
        gradient = [
            (tensor.grad if tensor.grad is not None else torch.zeros_like(tensor)).reshape(-1)
            for tensor in tensors
        ]
        return float(loss.item()), torch.cat(gradient).detach().cpu().numpy().astype(np.float64)

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
    for tensor in tensors:
        tensor.grad = None
    return evaluations
