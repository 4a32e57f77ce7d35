"""The Gaussian process of the qei proposer: a structure kernel and a spec kernel.

Imported only when a proposal is computed (it imports torch and gpytorch).

The model's input is ``z = [structure index, u]`` (``base.model_inputs``), with
every slot a structure does not use at the pad value, so such slots are constant
within a structure and never act as noise dimensions.

- ``SpecKernel`` sees ``u`` through features: plain specs as they are, and each
  joint axis given by two angles as its unit vector (halved, so its distances lie
  in [0, 1] like a spec's), or, for a sign-invariant axis, as the line through it
  (the outer product u u^T, whose distance sqrt(2 - 2 (u.v)^2) / sqrt(2) ignores the
  sign). One length scale per spec and one per axis (ARD over groups), with
  BoTorch's dimension-scaled log-normal prior (Hvarfner et al., 2024), or, for the
  GPs of a study of several objectives, the ``unit`` prior (``UNIT_LENGTHSCALE_PRIOR``,
  see there). A box's
  categorical param (``categories``: column -> number of choices) enters as the
  one-hot vector of its choice divided by sqrt(2): any two different choices are one
  length scale apart and no choice lies between two others (the Hamming distance of
  Optuna's GPSampler and of BoTorch's categorical kernel, here inside the same
  Matern or RBF as the other params, so it is fitted with them). Ints, stepped and
  log-scaled floats are plain specs of their encoded value (ordered; the acquisition
  keeps ints and choices discrete).
- ``StructureKernel`` is an RBF over the structures' coordinates in the fused
  geometry (``adservice.representation``), with one learned length scale: as it
  shrinks to 0 the kernel becomes the identity (every structure unrelated: the
  one-hot encoding's assumption), as it grows every structure looks alike.
- ``DesignKernel`` combines them as ``a Ks + b Kx + c Ks Kx``: a structure main
  effect, a spec main effect shared by every structure, and their interaction (a
  spec response of each structure's own), each weight fitted.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from typing import Any

import numpy as np
import torch
from gpytorch.constraints import GreaterThan
from gpytorch.kernels import Kernel
from gpytorch.priors import LogNormalPrior
from linear_operator.utils.warnings import NumericalWarning

from adservice.proposers.base import AxisColumns, SearchStructure

STRUCTURE_LENGTHSCALE_PRIOR = (math.log(0.5), 1.0)
"""(loc, scale) of the structure length scale's log-normal prior: structure distances
are scaled to a largest of 1 and a smallest of 0.05, so this spans unrelated to alike."""
UNIT_LENGTHSCALE_PRIOR = (0.0, 1.0)
"""(loc, scale) of each spec length scale's log-normal prior for the GPs of a study of
several objectives: a median of 1, the unit box's width, where the dimension-scaled
prior's is exp(sqrt(2) + ln(d) / 2) (10 at d = 6). Hypervolume rewards each
objective's extremes, which often lie on a face of the box; with the dimension-scaled
prior a GP of a few points extrapolates a trend out to the faces, and the observations
there, alike whenever the response is symmetric about the centre, then fit length
scales long enough to call the other inputs irrelevant. On DTLZ2 (d = 6) qei kept
sampling the corners: median hypervolume after 40 evaluations 0.087 over 10 seeds,
3 of them 0; with this prior 0.150 (one 0), and ZDT1 120.63 and 120.62
(bench/RESULTS.md). One objective keeps the dimension-scaled prior, with
which its benchmarks were measured."""
WEIGHT_PRIOR = (math.log(1.0 / 3.0), 1.0)
"""(loc, scale) of each component weight's log-normal prior (outcomes are standardised)."""

# Jitter added to a nearly singular matrix, a tiny fixed noise: expected here, and said
# by the trials' info. Filtered once: catch_warnings is not safe while others propose.
warnings.filterwarnings("ignore", category=NumericalWarning)


class SpecFeatures:
    """u -> the spec kernel's features, and which length-scale group each one has.

    The features are plain specs, then the axes that keep their sign (3 each), then
    the sign-invariant ones (6 each), then the categories' one-hot vectors; every axis
    is computed at once (a few tensor operations whatever their number: the fit and
    the acquisition differentiate through them hundreds of times an ask)."""

    def __init__(
        self,
        search: SearchStructure | None,
        spec_dim: int,
        categories: dict[int, int] | None = None,
        **tkw: object,
    ) -> None:
        axes = search.axes if search is not None else ()
        self.categories = sorted((categories or {}).items())
        on_axis = {column for axis in axes for column in (axis.theta, axis.phi) if column >= 0}
        skip = on_axis | {column for column, _ in self.categories}
        self.plain = [k for k in range(spec_dim) if k not in skip]
        self.axes = axes
        device = torch.device(str(tkw.get("device") or "cpu"))
        self.plain_index = torch.as_tensor(self.plain, dtype=torch.long, device=device)
        self.angles = [
            self._angle_table(search, axes, "theta", device),
            self._angle_table(search, axes, "phi", device),
        ]
        # which angles are all searched, and which some on a log scale
        self.angle_kinds = [(bool(t[1].all()), bool(t[5].any())) for t in self.angles]
        signs = [axis.sign_invariant for axis in axes]
        self.arrows = torch.as_tensor(
            [a for a, invariant in enumerate(signs) if not invariant],
            dtype=torch.long,
            device=device,
        )
        self.lines = torch.as_tensor(
            [a for a, invariant in enumerate(signs) if invariant], dtype=torch.long, device=device
        )
        # a line's features: the products unit[first] * unit[second] (the outer product
        # u u^T's upper triangle) times weight
        self.first, self.second = (
            torch.as_tensor(index, dtype=torch.long, device=device)
            for index in ([0, 1, 2, 0, 0, 1], [0, 1, 2, 1, 2, 2])
        )
        root2 = math.sqrt(2.0)
        self.weight = torch.as_tensor(
            [1.0 / root2, 1.0 / root2, 1.0 / root2, 1.0, 1.0, 1.0],
            dtype=torch.float64,
            device=device,
        )
        groups = list(range(len(self.plain)))
        for sign_invariant in (False, True):
            for number, axis in enumerate(axes):
                if axis.sign_invariant == sign_invariant:
                    groups += [len(self.plain) + number] * (6 if sign_invariant else 3)
        for number, (_, count) in enumerate(self.categories):
            groups += [len(self.plain) + len(axes) + number] * count
        self.n_groups = len(self.plain) + len(axes) + len(self.categories)
        self.group_index = torch.as_tensor(groups, dtype=torch.long, device=device)

    @staticmethod
    def _angle_table(
        search: SearchStructure | None,
        axes: tuple[AxisColumns, ...],
        which: str,
        device: Any,
    ) -> tuple[torch.Tensor, ...]:
        """Per axis: the slot of its angle (clamped to 0 when fixed), whether it is
        searched, its fixed value, the slot's start and width in radians, whether it
        is log-scaled (``{low, high, log: true}``: the angle is exp of the value)."""
        columns = [getattr(axis, which) for axis in axes]
        scales = [
            (*search.scale(c), search.is_log(c))
            if search is not None and c >= 0
            else (0.0, 0.0, False)
            for c in columns
        ]
        return (
            torch.as_tensor([max(c, 0) for c in columns], dtype=torch.long, device=device),
            torch.as_tensor([c >= 0 for c in columns], dtype=torch.bool, device=device),
            torch.as_tensor(
                [getattr(axis, f"{which}_fixed") for axis in axes],
                dtype=torch.float64,
                device=device,
            ),
            torch.as_tensor([scale[0] for scale in scales], dtype=torch.float64, device=device),
            torch.as_tensor([scale[1] for scale in scales], dtype=torch.float64, device=device),
            torch.as_tensor([scale[2] for scale in scales], dtype=torch.bool, device=device),
        )

    def _angle(self, u: torch.Tensor, which: int) -> tuple[torch.Tensor, torch.Tensor]:
        """Every axis's theta (``which`` 0) or phi (1) in radians (... x A): fixed, or its
        slot denormalised; and its derivative with respect to its slot (0 when fixed)."""
        column, searched, fixed, start, width, log = self.angles[which]
        all_searched, any_log = self.angle_kinds[which]
        angle = start + u[..., column] * width
        rate = width.expand_as(angle)
        if any_log:
            grown = torch.exp(angle)
            angle, rate = torch.where(log, grown, angle), torch.where(log, grown * width, rate)
        if all_searched:
            return angle, rate
        return torch.where(searched, angle, fixed), torch.where(searched, rate, 0.0)

    def __call__(self, u: torch.Tensor) -> torch.Tensor:
        return self.with_pullback(u)[0]

    def with_pullback(
        self, u: torch.Tensor
    ) -> tuple[torch.Tensor, Callable[[torch.Tensor], torch.Tensor]]:
        """The features of ``u``, and the pullback: the gradient with respect to ``u``
        of a function whose gradient with respect to the features is ``slopes``, in
        closed form (plain specs pass it on, an axis through its unit vector's or
        line's derivatives in its angles, a category's one-hot vector not at all: its
        choice is rounded), as autograd would give it."""
        parts = [u[..., self.plain_index]]
        if self.axes:
            (theta, theta_rate), (phi, phi_rate) = self._angle(u, 0), self._angle(u, 1)
            sin_theta, cos_theta = torch.sin(theta), torch.cos(theta)
            sin_phi, cos_phi = torch.sin(phi), torch.cos(phi)
            # ... x A x 3: each axis's unit vector
            unit = torch.stack([sin_theta * cos_phi, sin_theta * sin_phi, cos_theta], -1)
            shape = (*u.shape[:-1], -1)
            if len(self.arrows):
                parts.append(unit[..., self.arrows, :].reshape(shape) / 2.0)
            if len(self.lines):
                line = unit[..., self.lines, :]
                parts.append(
                    (line[..., self.first] * line[..., self.second] * self.weight).reshape(shape)
                )
        for column, count in self.categories:
            index = (u[..., column] * count - 0.5).round().clamp(0, count - 1).long()
            one_hot = torch.nn.functional.one_hot(index, count).to(u.dtype)
            parts.append(one_hot / math.sqrt(2.0))

        def pullback(slopes: torch.Tensor) -> torch.Tensor:
            gradient = torch.zeros_like(u)
            gradient[..., self.plain_index] = slopes[..., : len(self.plain)]
            if not self.axes:
                return gradient
            per_unit = torch.zeros_like(unit)
            offset = len(self.plain)
            if len(self.arrows):
                block = slopes[..., offset : offset + 3 * len(self.arrows)]
                per_unit[..., self.arrows, :] = block.reshape(*unit.shape[:-2], -1, 3) / 2.0
                offset += 3 * len(self.arrows)
            if len(self.lines):
                block = slopes[..., offset : offset + 6 * len(self.lines)]
                weighted = block.reshape(*unit.shape[:-2], -1, 6) * self.weight
                per_line = torch.zeros_like(line)
                per_line.index_add_(-1, self.first, weighted * line[..., self.second])
                per_line.index_add_(-1, self.second, weighted * line[..., self.first])
                per_unit[..., self.lines, :] = per_line
            per_x, per_y, per_z = per_unit.unbind(-1)
            per_theta = (per_x * cos_phi + per_y * sin_phi) * cos_theta - per_z * sin_theta
            per_phi = (per_y * cos_phi - per_x * sin_phi) * sin_theta
            gradient.index_add_(-1, self.angles[0][0], per_theta * theta_rate)
            gradient.index_add_(-1, self.angles[1][0], per_phi * phi_rate)
            return gradient

        return torch.cat(parts, dim=-1), pullback


class SpecKernel(Kernel):
    """RBF or Matern-5/2 over the spec features, one length scale per group."""

    has_lengthscale = True

    def __init__(self, features: SpecFeatures, *, rbf: bool, unit_prior: bool = False) -> None:
        d = features.n_groups
        if unit_prior:
            prior = LogNormalPrior(*UNIT_LENGTHSCALE_PRIOR)
        else:
            loc = math.sqrt(2.0) + 0.5 * math.log(max(d, 1))
            prior = LogNormalPrior(loc=loc, scale=math.sqrt(3.0))
        constraint = GreaterThan(2.5e-2, transform=None, initial_value=prior.mode)
        super().__init__(ard_num_dims=d, lengthscale_prior=prior, lengthscale_constraint=constraint)
        # one length scale per group, not per input column: gpytorch's input-width check
        # would compare the groups with the columns
        self.ard_num_dims = None
        self.features = features
        self.rbf = rbf

    def inputs(self, x: torch.Tensor) -> torch.Tensor:
        """The spec features of model inputs: free of hyperparameters, so a fit
        computes them once for its training points."""
        return self.features(x[..., 1:])

    def scaled(self, features: torch.Tensor) -> torch.Tensor:
        """Features divided by their length scales: the kernel is a function of the
        distance between two embeddings."""
        return features / self.lengthscale[..., self.features.group_index]

    def embed(self, x: torch.Tensor) -> torch.Tensor:
        return self.scaled(self.inputs(x))

    def from_embeddings(
        self, e1: torch.Tensor, e2: torch.Tensor, diag: bool = False
    ) -> torch.Tensor:
        squared = squared_distances(e1, e2, diag=diag)
        if self.rbf:
            return torch.exp(-0.5 * squared)
        root5 = math.sqrt(5.0) * squared.clamp_min(1e-30).sqrt()
        return (1.0 + root5 + root5**2 / 3.0) * torch.exp(-root5)

    def with_slope(self, squared: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The kernel at these squared distances and its derivative with respect to
        them: -k / 2 (RBF); -5/6 (1 + sqrt(5) r) exp(-sqrt(5) r) (Matern-5/2)."""
        if self.rbf:
            value = torch.exp(-0.5 * squared)
            return value, -0.5 * value
        root5 = math.sqrt(5.0) * squared.clamp_min(1e-30).sqrt()
        decay = torch.exp(-root5)
        return (1.0 + root5 + root5**2 / 3.0) * decay, (-5.0 / 6.0) * (1.0 + root5) * decay

    def forward(
        self, x1: torch.Tensor, x2: torch.Tensor, diag: bool = False, **params: object
    ) -> torch.Tensor:
        return self.from_embeddings(self.embed(x1), self.embed(x2), diag=diag)


class StructureKernel(Kernel):
    """RBF over the structures' fused-geometry coordinates, indexed by z[..., 0]."""

    has_lengthscale = True

    def __init__(self, coords: torch.Tensor) -> None:
        loc, scale = STRUCTURE_LENGTHSCALE_PRIOR
        prior = LogNormalPrior(loc=loc, scale=scale)
        super().__init__(
            lengthscale_prior=prior,
            lengthscale_constraint=GreaterThan(1e-3, transform=None, initial_value=prior.mode),
        )
        self.register_buffer("coords", coords)

    def inputs(self, x: torch.Tensor) -> torch.Tensor:
        """The structures' coordinates of model inputs (free of hyperparameters)."""
        return self.coords[x[..., 0].round().clamp(0, self.coords.shape[0] - 1).long()]

    def scaled(self, coords: torch.Tensor) -> torch.Tensor:
        return coords / self.lengthscale

    def embed(self, x: torch.Tensor) -> torch.Tensor:
        return self.scaled(self.inputs(x))

    def from_embeddings(
        self, e1: torch.Tensor, e2: torch.Tensor, diag: bool = False
    ) -> torch.Tensor:
        return torch.exp(-0.5 * squared_distances(e1, e2, diag=diag))

    def forward(
        self, x1: torch.Tensor, x2: torch.Tensor, diag: bool = False, **params: object
    ) -> torch.Tensor:
        return self.from_embeddings(self.embed(x1), self.embed(x2), diag=diag)


def squared_distances(e1: torch.Tensor, e2: torch.Tensor, diag: bool = False) -> torch.Tensor:
    """Squared Euclidean distances between the rows of two embeddings (``diag``: row i
    of e1 to row i of e2), by the quadratic expansion, floored at 0: gpytorch's
    ``covar_dist`` in fewer operations, which the fit and the acquisition differentiate
    through hundreds of times an ask."""
    if diag:
        if e1 is e2:
            return torch.zeros(e1.shape[:-1], dtype=e1.dtype, device=e1.device)
        return ((e1 - e2) ** 2).sum(-1)
    norms1 = (e1 * e1).sum(-1, keepdim=True)
    norms2 = norms1 if e2 is e1 else (e2 * e2).sum(-1, keepdim=True)
    return (norms1 - 2.0 * e1 @ e2.transpose(-2, -1) + norms2.transpose(-2, -1)).clamp_min(0.0)


class DesignKernel(Kernel):
    """``a Ks + b Kx + c Ks Kx`` with several structures, ``Kx`` alone otherwise.

    One kernel object, computed directly: gpytorch's sums, products and scalings of
    kernels each evaluate lazily and compute a shared part twice, which made the fit
    and the acquisition several times slower. ``embed`` and ``from_embeddings`` let
    the posterior embed the training points once.
    """

    def __init__(self, spec: SpecKernel, structure: StructureKernel | None) -> None:
        super().__init__()
        self.spec = spec
        self.structure = structure
        if structure is not None:
            loc, scale = WEIGHT_PRIOR
            self.register_parameter("raw_weights", torch.nn.Parameter(torch.zeros(3)))
            self.register_constraint(
                "raw_weights", GreaterThan(1e-6, transform=None, initial_value=1.0 / 3.0)
            )
            self.register_prior(
                "weights_prior",
                LogNormalPrior(loc=loc, scale=scale),
                lambda module: module.weights,
                lambda module, value: module._set_weights(value),
            )

    @property
    def weights(self) -> torch.Tensor:
        return self.raw_weights_constraint.transform(self.raw_weights)

    @weights.setter
    def weights(self, value: torch.Tensor) -> None:
        self._set_weights(value)

    def _set_weights(self, value: torch.Tensor) -> None:
        value = torch.as_tensor(value).to(self.raw_weights)
        self.initialize(raw_weights=self.raw_weights_constraint.inverse_transform(value))

    def inputs(self, x: torch.Tensor) -> Embedding:
        """What ``embed`` scales: the part of the embedding that no hyperparameter
        changes."""
        return (
            self.spec.inputs(x),
            self.structure.inputs(x) if self.structure is not None else None,
        )

    def scaled(self, inputs: Embedding) -> Embedding:
        spec, structure = inputs
        if self.structure is None or structure is None:
            return self.spec.scaled(spec), None
        return self.spec.scaled(spec), self.structure.scaled(structure)

    def embed(self, x: torch.Tensor) -> Embedding:
        return self.scaled(self.inputs(x))

    def from_embeddings(self, e1: Embedding, e2: Embedding, diag: bool = False) -> torch.Tensor:
        spec = self.spec.from_embeddings(e1[0], e2[0], diag=diag)
        if self.structure is None:
            return spec
        assert e1[1] is not None and e2[1] is not None
        structure = self.structure.from_embeddings(e1[1], e2[1], diag=diag)
        a, b, c = self.weights
        return a * structure + b * spec + c * structure * spec

    def forward(
        self, x1: torch.Tensor, x2: torch.Tensor, diag: bool = False, **params: object
    ) -> torch.Tensor:
        e1 = self.embed(x1)
        return self.from_embeddings(e1, e1 if x2 is x1 else self.embed(x2), diag=diag)


Embedding = tuple[torch.Tensor, torch.Tensor | None]
"""A point set embedded by the spec kernel and by the structure kernel (if any)."""


def design_kernel(
    search: SearchStructure | None,
    spec_dim: int,
    *,
    kernel: str,
    categories: dict[int, int] | None = None,
    unit_prior: bool = False,
    **tkw: object,
) -> DesignKernel:
    """The model's covariance (see the module docstring); ``unit_prior``: the spec length
    scales' ``UNIT_LENGTHSCALE_PRIOR`` instead of the dimension-scaled one."""
    features = SpecFeatures(search, spec_dim, categories, **tkw)
    spec = SpecKernel(features, rbf=kernel == "rbf", unit_prior=unit_prior)
    structure = None
    if search is not None and search.n_structures > 1:
        structure = StructureKernel(torch.as_tensor(search.structure_coords, **tkw))  # type: ignore[arg-type]
    return DesignKernel(spec, structure).to(**tkw)


def structure_correlation(model: Any, search: SearchStructure, tkw: dict[str, Any]) -> float:
    """How alike the fitted model holds the structures: the mean correlation between
    two structures' designs with the same specs (all at the pad value); 0 is the
    one-hot encoding's assumption, 1 a structure-blind model."""
    count = search.n_structures
    Z = np.column_stack([np.arange(count), np.full((count, search.spec_dim), search.pad)])
    with torch.no_grad():
        points = torch.as_tensor(Z, **tkw)
        # the kernel's own forward: gpytorch's call wraps it in a lazy tensor that cost
        # more than the 8 x 8 matrix
        K = model.covar_module.forward(points, points).cpu().numpy()
    scale = np.sqrt(np.diag(K))
    correlation = K / np.outer(scale, scale)
    return round(float(correlation[~np.eye(count, dtype=bool)].mean()), 6)


def structure_lengthscale(model: Any) -> float:
    structure = model.covar_module.structure
    return round(float(structure.lengthscale.detach().cpu().reshape(-1)[0]), 6)
