"""A fitted GP's posterior from one Cholesky factor, with pending points as Kriging
believers, and the analytic acquisitions of one ask built on it: LogEI for one
objective, constrained LogEI for one with outcome constraints.

Imported only when a proposal is computed (it imports torch)."""

from __future__ import annotations

import copy
from collections.abc import Callable
from typing import Any

import numpy as np
import torch

from adservice.proposers.arrays import ArrayPosterior
from adservice.proposers.gpmodel import DesignKernel, squared_distances


class Posterior:
    """The fitted GP's posterior at new points, in the outcome's own scale, from one
    Cholesky factor. ``believing`` adds pending points as observations of the model's
    own mean there (Kriging believer), which keeps the mean and takes the variance
    away near them; ``beliefs`` holds those means."""

    def __init__(self, model: object) -> None:
        with torch.no_grad():
            self.kernel: DesignKernel = model.covar_module  # type: ignore[attr-defined]
            self.constant = model.mean_module.constant.reshape(())  # type: ignore[attr-defined]
            transform = model.outcome_transform  # type: ignore[attr-defined]
            self.offset = transform.means.reshape(())
            self.scale = transform.stdvs.reshape(())
            train = model.train_inputs[0]  # type: ignore[attr-defined]
            noise = model.likelihood.noise.reshape(-1)  # type: ignore[attr-defined]
            noise = noise.expand(len(train)) if noise.numel() == 1 else noise
            self._factor(train, model.train_targets, noise)  # type: ignore[attr-defined]
        self.beliefs = torch.zeros(0, dtype=train.dtype, device=train.device)

    def believing(self, pending: torch.Tensor) -> Posterior:
        """This posterior with ``pending`` observed at its own mean."""
        believer = copy.copy(self)
        with torch.no_grad():
            beliefs = self.mean_sigma(pending)[0]
            believer._factor(
                torch.cat([self.points, pending]),
                torch.cat([self.targets, (beliefs - self.offset) / self.scale]),
                torch.cat([self.noise, self.noise.min().expand(len(pending))]),
            )
        believer.beliefs = beliefs
        return believer

    def keeping(self, keep: torch.Tensor) -> Posterior:
        """This posterior conditioned only on the observations ``keep`` (a mask) holds."""
        kept = copy.copy(self)
        with torch.no_grad():
            kept._factor(self.points[keep], self.targets[keep], self.noise[keep])
        return kept

    def _factor(self, points: torch.Tensor, targets: torch.Tensor, noise: torch.Tensor) -> None:
        self.points, self.targets, self.noise = points, targets, noise
        self.embedded = self.kernel.embed(points)
        K = self.kernel.from_embeddings(self.embedded, self.embedded) + torch.diag(noise)
        self.cholesky = torch.linalg.cholesky(K)
        residual = (targets - self.constant).unsqueeze(-1)
        self.alpha = torch.cholesky_solve(residual, self.cholesky).squeeze(-1)
        self._structure_rows: torch.Tensor | None = None
        self.arrays: ArrayPosterior | None = None
        """This posterior in NumPy (``arrays.ArrayPosterior.of``), built on first use."""

    def structure_rows(self) -> torch.Tensor:
        """The structure kernel between every structure and the points (S x n): a
        local search moves specs only, so its candidates' rows are looked up."""
        structure = self.kernel.structure
        assert structure is not None and self.embedded[1] is not None
        if self._structure_rows is None:
            with torch.no_grad():
                self._structure_rows = structure.from_embeddings(
                    structure.scaled(structure.coords), self.embedded[1]
                )
        return self._structure_rows

    def mean_sigma(self, X: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Mean and standard deviation at the rows of X (b x D)."""
        embedded = self.kernel.embed(X)
        cross = self.kernel.from_embeddings(embedded, self.embedded)
        mean = self.constant + cross @ self.alpha
        solved = torch.linalg.solve_triangular(self.cholesky, cross.T, upper=False)
        prior = self.kernel.from_embeddings(embedded, embedded, diag=True)
        variance = (prior - (solved**2).sum(0)).clamp_min(1e-12)
        return self.offset + self.scale * mean, self.scale * variance.sqrt()

    def log_ei_with_gradient(
        self, X: torch.Tensor, best_f: float
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """LogEI over ``best_f`` at the rows of X (b x D) and its gradient with respect
        to them, in closed form: the chain rule written out through LogEI, the mean and
        variance, the cross-covariance and the squared distances of the spec
        embeddings, and the spec features (``SpecFeatures.with_pullback``). Autograd's
        backward pass over the same few small matrices cost more than the forward one,
        and a local search evaluates this a hundred times an ask. The structure column
        (rounded to an index) gets no gradient, as under autograd."""
        from botorch.acquisition.analytic import _log_ei_helper

        kernel, spec = self.kernel, self.kernel.spec
        features_of = spec.features
        u = X[..., 1:]
        with torch.no_grad():
            features, pullback = features_of.with_pullback(u)
            scales = spec.lengthscale.reshape(-1)[features_of.group_index]
            embedded = features / scales
            trained = self.embedded[0]
            squared = squared_distances(embedded, trained)
            cross, slope = spec.with_slope(squared)
            prior: torch.Tensor | float = 1.0
            if kernel.structure is not None:
                rows = self.structure_rows()
                structure = rows[X[..., 0].round().clamp(0, len(rows) - 1).long()]
                a, b, c = kernel.weights
                mix = b + c * structure
                cross, slope = a * structure + mix * cross, mix * slope
                prior = a + b + c
            mean = self.constant + cross @ self.alpha
            solved = torch.linalg.solve_triangular(self.cholesky, cross.T, upper=False)
            unclamped = prior - (solved**2).sum(0)
            root = unclamped.clamp_min(1e-12).sqrt()
            sigma = self.scale * root
            z = (self.offset + self.scale * mean - best_f) / sigma
            log_h = _log_ei_helper(z)
            value = log_h + sigma.log()
            # d log_h / dz = Phi(z) / (phi(z) + z Phi(z))
            ratio = torch.exp(torch.special.log_ndtr(z) - log_h)
            per_mean = ratio * self.scale / sigma
            per_variance = torch.where(unclamped > 1e-12, (1.0 - ratio * z) / (2.0 * root**2), 0.0)
            # d variance / d cross = -2 K^-1 cross
            inverse_cross = torch.linalg.solve_triangular(self.cholesky.T, solved, upper=True).T
            per_squared = (
                per_mean[:, None] * self.alpha[None, :]
                - 2.0 * per_variance[:, None] * inverse_cross
            ) * slope
            per_embedded = 2.0 * (
                embedded * per_squared.sum(-1, keepdim=True) - per_squared @ trained
            )
            gradient = torch.zeros_like(X)
            gradient[..., 1:] = pullback(per_embedded / scales)
        return value, gradient


class LogEI:
    """Analytic LogEI (Ament et al., 2023) on ``posterior``: b x 1 x D -> b; its
    ``value_and_grad`` (b x D -> values, gradient) is what the local searches call
    (``Posterior.log_ei_with_gradient``). On the CPU it also has ``on_arrays``, the
    same in NumPy (``arrays``), which the search calls instead (``acquisition``)."""

    def __init__(self, posterior: Posterior, best_f: float) -> None:
        self.posterior, self.best_f = posterior, best_f
        arrays = ArrayPosterior.of(posterior)
        self.on_arrays = None if arrays is None else OnArrays(arrays, best_f)

    def __call__(self, Z: torch.Tensor) -> torch.Tensor:
        from botorch.acquisition.analytic import _log_ei_helper

        mean, sigma = self.posterior.mean_sigma(Z.squeeze(-2))
        return _log_ei_helper((mean - self.best_f) / sigma) + sigma.log()

    def value_and_grad(self, X: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.posterior.log_ei_with_gradient(X, self.best_f)


class OnArrays:
    """LogEI on a posterior's arrays: ``values`` (b x D -> b) and ``with_gradient``
    (b x D -> values, gradient), float64 NumPy arrays in and out."""

    def __init__(self, arrays: ArrayPosterior, best_f: float) -> None:
        self.arrays, self.best_f = arrays, best_f

    def values(self, X: np.ndarray) -> np.ndarray:
        return self.arrays.log_ei(X, self.best_f)

    def with_gradient(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.arrays.log_ei_with_gradient(X, self.best_f)


class AnalyticLogEI:
    """Analytic LogEI for the greedy steps of one ask: the posterior is factored once,
    and each step adds its pending points as Kriging believers (``Posterior``). The
    incumbent is the best observation or, for a noisy study, the best posterior mean
    at the observed points; a believed value above it becomes the incumbent, otherwise
    the model would see a sure improvement at (and next to) a pending point."""

    def __init__(self, model: Any, train_Z: torch.Tensor, y: np.ndarray, noisy: bool) -> None:
        self.posterior = Posterior(model)
        with torch.no_grad():
            best = self.posterior.mean_sigma(train_Z)[0].max() if noisy else y.max()
        self.incumbent = float(best)

    def step(self, pending: torch.Tensor | None) -> tuple[Callable, str]:
        """The acquisition given these pending points, and its name."""
        if pending is None:
            return LogEI(self.posterior, self.incumbent), "LogEI"
        believer = self.posterior.believing(pending)
        incumbent = max(self.incumbent, float(believer.beliefs.max()))
        return LogEI(believer, incumbent), "LogEI-believer"


class AnalyticConstrainedLogEI:
    """Analytic constrained LogEI (Gardner et al., 2014; BoTorch's
    ``LogConstrainedExpectedImprovement``) for one objective with outcome constraints:
    LogEI of the objective's GP over the best *feasible* observation (for a noisy
    study the best posterior mean at the feasible observations) plus the log
    probability that every constraint's GP is at or below 0 there, the GPs taken as
    independent. With no feasible observation yet it is the log probability of
    feasibility alone. Pending points are Kriging believers of every GP, as in
    ``AnalyticLogEI``; a believed value above the incumbent at a point whose
    believed slacks are all <= 0 becomes the incumbent."""

    def __init__(
        self,
        model: Any,
        constraint_models: list[Any],
        train_Z: torch.Tensor,
        y: np.ndarray,
        feasible: np.ndarray,
        noisy: bool,
    ) -> None:
        self.posterior = Posterior(model)
        self.constraints = [Posterior(m) for m in constraint_models]
        self.incumbent: float | None = None
        if feasible.any():
            with torch.no_grad():
                if noisy:
                    means = self.posterior.mean_sigma(train_Z)[0].cpu().numpy()
                    self.incumbent = float(means[feasible].max())
                else:
                    self.incumbent = float(y[feasible].max())

    def step(self, pending: torch.Tensor | None) -> tuple[Callable, str]:
        """The acquisition given these pending points, and its name."""
        objective, constraints, incumbent = self.posterior, self.constraints, self.incumbent
        if pending is not None:
            objective = objective.believing(pending)
            constraints = [c.believing(pending) for c in constraints]
            believed_feasible = torch.stack([c.beliefs <= 0 for c in constraints]).all(dim=0)
            if incumbent is not None and bool(believed_feasible.any()):
                incumbent = max(incumbent, float(objective.beliefs[believed_feasible].max()))
        name = "LogPoF" if incumbent is None else "LogCEI"
        name += "" if pending is None else "-believer"

        def acquisition(Z: torch.Tensor) -> torch.Tensor:
            X = Z.squeeze(-2)
            log_feasible = torch.zeros(X.shape[:-1], dtype=X.dtype, device=X.device)
            for constraint in constraints:
                mean, sigma = constraint.mean_sigma(X)
                log_feasible = log_feasible + torch.special.log_ndtr(-mean / sigma)
            if incumbent is None:
                return log_feasible
            from botorch.acquisition.analytic import _log_ei_helper

            mean, sigma = objective.mean_sigma(X)
            return _log_ei_helper((mean - incumbent) / sigma) + sigma.log() + log_feasible

        return acquisition, name
