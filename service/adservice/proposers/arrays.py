"""LogEI and its gradient on a CPU posterior in NumPy: the same arithmetic as
``Posterior.log_ei_with_gradient`` and ``LogEI.__call__`` (equal within rounding,
tested), for the acquisition's local searches and raw-sample screens; and the spec
kernel's ``with_slope``, which the fit's ``likelihood.ArrayLogPosterior`` also uses.

At n = 30 on the 8-tree, 13-spec space one evaluation is about a hundred operations on
matrices of a few hundred numbers, and an ask makes a hundred or more: torch's dispatch
per operation (5 to 10 us) cost more than the arithmetic, NumPy's is about 1 us
(bench/RESULTS.md). ``ArrayPosterior.of`` copies what a ``Posterior`` holds to arrays
once per posterior (a believer or a kept posterior is a new one), so nothing it reads
can be stale. Only float64 posteriors on the CPU have one; on a GPU the torch path runs.

Imported only when a proposal is computed (it imports torch through ``gpmodel``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
from scipy.linalg import solve_triangular
from scipy.linalg.blas import dtrmm
from scipy.special import erfcx, log_ndtr, ndtr

if TYPE_CHECKING:
    from adservice.proposers.gpmodel import SpecFeatures

Posterior = Any
"""A ``posterior.Posterior`` (which imports this module: not imported back)."""

_VARIANCE_FLOOR = 1e-12
_LOG_SQRT_2PI = 0.5 * math.log(2.0 * math.pi)
_LOG_SQRT_PI_DIV_2 = 0.5 * math.log(math.pi / 2.0)
_NEG_INV_SQRT_EPS = -1e6
"""``_log_ei_helper``'s second threshold in double precision."""


def _numpy(tensor: torch.Tensor) -> np.ndarray:
    """A copy of an array kept (a CPU tensor's ``numpy()`` shares its memory): an array
    posterior must not change with a tensor its posterior reads, whatever is done to
    that tensor later. What is kept is the model's small arrays and the n-long, n x p
    and structures x n ones; the n x n factor is only read, into its inverse, and not
    copied."""
    return tensor.detach().cpu().numpy().copy()


def log_ei_helper(u: np.ndarray) -> np.ndarray:
    """log(phi(u) + u Phi(u)), branch for branch as BoTorch's ``_log_ei_helper``."""
    upper = np.maximum(u, -1.0)
    log_upper = np.log(np.exp(-0.5 * upper**2 - _LOG_SQRT_2PI) + upper * ndtr(upper))
    lower = np.minimum(u, -1.0)
    bounded = np.maximum(lower, _NEG_INV_SQRT_EPS)
    w = np.log(erfcx(-bounded / math.sqrt(2.0)) * np.abs(bounded)) + _LOG_SQRT_PI_DIV_2
    log1mexp = np.where(w > -math.log(2.0), np.log(-np.expm1(w)), np.log1p(-np.exp(w)))
    tail = np.where(u > _NEG_INV_SQRT_EPS, log1mexp, -2.0 * np.log(np.abs(lower)))
    return np.where(u > -1.0, log_upper, -0.5 * u**2 - _LOG_SQRT_2PI + tail)


def with_slope(squared: np.ndarray, *, rbf: bool) -> tuple[np.ndarray, np.ndarray]:
    """``SpecKernel.with_slope`` in NumPy: the kernel at these squared distances and its
    derivative with respect to them."""
    if rbf:
        value = np.exp(-0.5 * squared)
        return value, -0.5 * value
    root5 = math.sqrt(5.0) * np.sqrt(np.maximum(squared, 1e-30))
    decay = np.exp(-root5)
    return (1.0 + root5 + root5**2 / 3.0) * decay, (-5.0 / 6.0) * (1.0 + root5) * decay


def _times_inverse_factor(
    inverse_factor: np.ndarray, B: np.ndarray, *, transposed: bool = False
) -> np.ndarray:
    """L^-1 B (or L^-T B) for the lower-triangular ``inverse_factor`` (Fortran order):
    BLAS's triangular product reads only the triangle, half a general product's
    arithmetic and memory traffic. Past a few hundred observations the matrix does not
    fit the cache, and these two products were most of a local search's time (at
    2,048 training points a third of a general product's CPU; bench/RESULTS.md)."""
    return dtrmm(1.0, inverse_factor, B, lower=1, trans_a=int(transposed))


class ArrayFeatures:
    """``SpecFeatures`` in NumPy: the features of ``u`` (b x p) and their pullback."""

    def __init__(self, features: SpecFeatures) -> None:
        self.plain = _numpy(features.plain_index)
        self.n_axes = len(features.axes)
        self.arrows, self.lines = _numpy(features.arrows), _numpy(features.lines)
        self.first, self.second = _numpy(features.first), _numpy(features.second)
        self.weight = _numpy(features.weight)
        # a line's six products back onto the unit vector's entries they multiply
        self.onto_first, self.onto_second = np.eye(3)[self.first], np.eye(3)[self.second]
        self.angles = [tuple(_numpy(t) for t in table) for table in features.angles]
        self.categories = features.categories

    def _angle(self, u: np.ndarray, which: int) -> tuple[np.ndarray, np.ndarray]:
        column, searched, fixed, start, width, log = self.angles[which]
        angle = start + u[:, column] * width
        rate = width
        if log.any():
            grown = np.exp(angle)
            angle, rate = np.where(log, grown, angle), np.where(log, grown * width, rate)
        return np.where(searched, angle, fixed), np.where(searched, rate, 0.0)

    def with_pullback(self, u: np.ndarray) -> tuple[np.ndarray, Callable[[np.ndarray], np.ndarray]]:
        """As ``SpecFeatures.with_pullback``."""
        b = len(u)
        parts = [u[:, self.plain]]
        if self.n_axes:
            (theta, theta_rate), (phi, phi_rate) = self._angle(u, 0), self._angle(u, 1)
            sin_theta, cos_theta = np.sin(theta), np.cos(theta)
            sin_phi, cos_phi = np.sin(phi), np.cos(phi)
            unit = np.stack([sin_theta * cos_phi, sin_theta * sin_phi, cos_theta], -1)
            if len(self.arrows):
                parts.append(unit[:, self.arrows, :].reshape(b, -1) / 2.0)
            if len(self.lines):
                line = unit[:, self.lines, :]
                products = line[..., self.first] * line[..., self.second] * self.weight
                parts.append(products.reshape(b, -1))
        for column, count in self.categories:
            index = np.clip(np.round(u[:, column] * count - 0.5), 0, count - 1).astype(np.int64)
            parts.append(np.eye(count)[index] / math.sqrt(2.0))

        def pullback(slopes: np.ndarray) -> np.ndarray:
            gradient = np.zeros_like(u)
            gradient[:, self.plain] = slopes[:, : len(self.plain)]
            if not self.n_axes:
                return gradient
            per_unit = np.zeros_like(unit)
            offset = len(self.plain)
            if len(self.arrows):
                block = slopes[:, offset : offset + 3 * len(self.arrows)]
                per_unit[:, self.arrows, :] = block.reshape(b, -1, 3) / 2.0
                offset += 3 * len(self.arrows)
            if len(self.lines):
                block = slopes[:, offset : offset + 6 * len(self.lines)]
                weighted = block.reshape(b, -1, 6) * self.weight
                per_unit[:, self.lines, :] = (
                    weighted * line[..., self.second]
                ) @ self.onto_first + (weighted * line[..., self.first]) @ self.onto_second
            per_x, per_y, per_z = per_unit[..., 0], per_unit[..., 1], per_unit[..., 2]
            per_theta = (per_x * cos_phi + per_y * sin_phi) * cos_theta - per_z * sin_theta
            per_phi = (per_y * cos_phi - per_x * sin_phi) * sin_theta
            for which, slope in ((0, per_theta * theta_rate), (1, per_phi * phi_rate)):
                np.add.at(gradient.T, self.angles[which][0], slope.T)  # a view
            return gradient

        return np.concatenate(parts, axis=1), pullback


class ArrayPosterior:
    """A CPU ``Posterior``'s arrays, and LogEI with and without its gradient on them."""

    def __init__(self, posterior: Posterior) -> None:
        kernel, spec = posterior.kernel, posterior.kernel.spec
        self.features = ArrayFeatures(spec.features)
        self.scales = _numpy(spec.lengthscale.reshape(-1)[spec.features.group_index])
        self.rbf = spec.rbf
        self.trained = _numpy(posterior.embedded[0])
        self.trained_norms = (self.trained**2).sum(-1)
        self.alpha = _numpy(posterior.alpha)
        # L^-1, once: two products per evaluation instead of two triangular solves;
        # Fortran order for BLAS's triangular product (``_times_inverse_factor``)
        self.inverse_factor = np.asfortranarray(
            solve_triangular(
                posterior.cholesky.detach().cpu().numpy(), np.eye(len(self.alpha)), lower=True
            )
        )
        self.constant = float(posterior.constant.detach())
        self.offset, self.scale = float(posterior.offset.detach()), float(posterior.scale.detach())
        self.structure_rows: np.ndarray | None = None
        self.weights = (0.0, 1.0, 0.0)
        if kernel.structure is not None:
            self.structure_rows = _numpy(posterior.structure_rows())
            a, b, c = (float(w) for w in kernel.weights.detach())
            self.weights = (a, b, c)

    @staticmethod
    def of(posterior: Posterior) -> ArrayPosterior | None:
        """The posterior's arrays, built once per posterior; None off the CPU or float64."""
        points = posterior.points
        if points.device.type != "cpu" or points.dtype != torch.float64:
            return None
        if posterior.arrays is None:
            posterior.arrays = ArrayPosterior(posterior)
        return posterior.arrays

    def _cross(
        self, X: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, Callable[[np.ndarray], np.ndarray]]:
        """The embedding of X's specs, its covariance with the observations and that
        covariance's slope in the squared spec distances, the prior variance, and the
        features' pullback."""
        features, pullback = self.features.with_pullback(X[:, 1:])
        embedded = features / self.scales
        squared = np.maximum(
            (embedded**2).sum(-1)[:, None] - 2.0 * embedded @ self.trained.T + self.trained_norms,
            0.0,
        )
        cross, slope = with_slope(squared, rbf=self.rbf)
        a, b, c = self.weights
        prior = 1.0
        if self.structure_rows is not None:
            rows = self.structure_rows
            index = np.clip(np.round(X[:, 0]), 0, len(rows) - 1).astype(np.int64)
            structure = rows[index]
            mix = b + c * structure
            cross, slope = a * structure + mix * cross, mix * slope
            prior = a + b + c
        return embedded, cross, slope, prior, pullback

    def log_ei(self, X: np.ndarray, best_f: float) -> np.ndarray:
        """LogEI over ``best_f`` at the rows of X (b x D)."""
        _, cross, _, prior, _ = self._cross(X)
        return self._log_ei(cross, prior, best_f)[0]

    def _log_ei(self, cross: np.ndarray, prior: float, best_f: float) -> tuple[np.ndarray, ...]:
        """LogEI, log h(z), z, the standard deviation in standardised units and
        unclamped, and L^-1 cross^T."""
        mean = self.constant + cross @ self.alpha
        solved = _times_inverse_factor(self.inverse_factor, cross.T)
        unclamped = prior - (solved**2).sum(0)
        root = np.sqrt(np.maximum(unclamped, _VARIANCE_FLOOR))
        sigma = self.scale * root
        z = (self.offset + self.scale * mean - best_f) / sigma
        log_h = log_ei_helper(z)
        return log_h + np.log(sigma), log_h, z, root, unclamped, solved

    def log_ei_with_gradient(self, X: np.ndarray, best_f: float) -> tuple[np.ndarray, np.ndarray]:
        """LogEI and its gradient with respect to X, as ``Posterior.log_ei_with_gradient``."""
        embedded, cross, slope, prior, pullback = self._cross(X)
        value, log_h, z, root, unclamped, solved = self._log_ei(cross, prior, best_f)
        ratio = np.exp(log_ndtr(z) - log_h)
        per_mean = ratio * self.scale / (self.scale * root)
        per_variance = np.where(
            unclamped > _VARIANCE_FLOOR, (1.0 - ratio * z) / (2.0 * root**2), 0.0
        )
        inverse_cross = _times_inverse_factor(self.inverse_factor, solved, transposed=True).T
        per_squared = (
            per_mean[:, None] * self.alpha[None, :] - 2.0 * per_variance[:, None] * inverse_cross
        ) * slope
        per_embedded = 2.0 * (
            embedded * per_squared.sum(-1, keepdims=True) - per_squared @ self.trained
        )
        gradient = np.zeros_like(X)
        gradient[:, 1:] = pullback(per_embedded / self.scales)
        return value, gradient
