"""The local model of a very long history: a trust region around the incumbent, as in
TuRBO (Eriksson et al. 2019), for a continuous box past ``TRUST_FROM`` observations.

Past ``max_train`` observations a GP trains on a subset of them (``subset``) and its
expected improvement is maximised over the whole box. At 3,000 and 10,000 random
observations that closed more of the gap to the optimum than a trust region did, but at
100,000 its asks were worse than random points: the model explored where its subset left
it uncertain rather than improving the best (bench/RESULTS.md, "Asks past thousands of
observations"). Past ``TRUST_FROM`` observations, instead:

- the GP trains on ``LOCAL_TRAIN`` observations: three quarters the best, a quarter
  others near the best (``local_training``);
- the acquisition is maximised inside a box around the best (``TrustBox``), whose side
  along each dimension follows the fitted length scales (TuRBO's weights, their
  geometric mean 1), clipped to the unit box, and whose volume is the share of the unit
  box those training points would fill if they were the nearest (``LOCAL_TRAIN / n``).

TuRBO's own box is not sized after clipping: at 3,000 observations of Hartmann6 it held
1% of the unit box instead of 34%. TuRBO's GP trains on the observations inside its box:
on Rosenbrock, whose history's best lies far from the optimum along a curved valley,
the 1024 nearest the best closed none of the gap at 100,000 on any of 10 seeds (the
best trace the valley). The best alone
leave the best's own neighbourhood nearly empty: on Hartmann6 at 100,000, 3 of 10 seeds
closed none of the gap, their log EI flat at -15 inside the box; with a quarter of near
points they closed all of it, the other seeds as before. That costs Rosenbrock at
100,000 a tenth of the gap at the median (0.68 against 0.78 over 20 seeds, 16 lower),
the price of no seed left where it started (bench/RESULTS.md, "Twenty asks at 10,000
to 100,000"). The side does not adapt
to successes and failures as TuRBO's does (each ask is computed from the history
alone): the box shrinks as the history grows.

Only a box of continuous parameters with one outcome gets it (``applies``): a design
space's structure, a typed box's discrete columns and several outcomes keep the subset.
``options.large_history`` chooses either model past ``max_train`` whatever n is. Imports
no torch at import.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    import torch

TRUST_FROM = 20_000
"""Past this many observations a continuous box's default model is the trust region (below
it, the subset): between the 10,000 where the subset did better and the 100,000 where only
the trust region improved on random points (bench/RESULTS.md); not measured in between."""
LOCAL_TRAIN = 1024
"""Observations the trust region's GP trains on by default (chosen by time:
bench/RESULTS.md, "Asks past thousands of observations")."""
MIN_SIDE = 2.0**-7
"""TuRBO's least side of the trust region (before the length-scale weights)."""


def applies(*, structure: Any, box: Any, n_outcomes: int) -> bool:
    """Whether a study's long history gets the trust region: a plain box (no design
    structure, no int, stepped or categorical column) with one outcome."""
    if structure is not None or n_outcomes != 1:
        return False
    return box is None or not (box.ordinal or box.categorical)


LOCAL_NEAR = 0.25
"""The share of the trust region's training points that are near the best (the rest are
the best): see the module docstring."""
NEAR_REACH = 2
"""The near points are spread evenly, by distance, over the ``NEAR_REACH * size`` others
nearest the best (about twice the trust box's share of a uniform history), not the very
nearest: on Rosenbrock at 100,000 observations the 256 nearest closed none of the gap
on 2 of 10 seeds, the spread on 1 (bench/RESULTS.md). A history of fewer than
``size * (1 - LOCAL_NEAR + NEAR_REACH)`` observations (only with ``max_train`` and
``large_history: trust-region``) has fewer others than that: the near points then
spread over all of them."""


def local_training(Z: np.ndarray, y: np.ndarray, *, size: int) -> np.ndarray | None:
    """Indices (ascending: trial order) of the GP's ``size`` training observations: the
    best (``y`` to be maximised) and, a ``LOCAL_NEAR`` share of them, others near the
    best (max-norm over the model inputs ``Z``; see ``NEAR_REACH``); None when there are
    no more than ``size``."""
    if len(y) <= size:
        return None
    n_near = int(size * LOCAL_NEAR)
    best = np.argpartition(-y, size - n_near - 1)[: size - n_near]
    if n_near == 0:
        return np.sort(best)
    distance = np.max(np.abs(Z - Z[int(np.argmax(y))]), axis=1)
    distance[best] = np.inf
    reach = min(NEAR_REACH * size, len(y) - len(best))
    nearest = np.argpartition(distance, reach - 1)[:reach]
    nearest = nearest[np.argsort(distance[nearest], kind="stable")]
    near = nearest[np.linspace(0, reach - 1, n_near).round().astype(int)]
    return np.sort(np.concatenate([best, near]))


@dataclass(frozen=True)
class TrustBox:
    """A box inside the unit box of the spec columns of model inputs (column 0, the
    structure index, is left alone), and the maps between it and the unit box the
    acquisition search works in."""

    low: np.ndarray
    high: np.ndarray
    side: float
    """The side before the length-scale weights and the clipping (TuRBO's L)."""

    @property
    def width(self) -> np.ndarray:
        return self.high - self.low

    def to_unit(self, Z: np.ndarray, *, clip: bool = True) -> np.ndarray:
        """Model inputs as the search's coordinates (outside the box: clipped onto it,
        unless ``clip`` is False)."""
        out = np.array(Z, dtype=np.float64, copy=True)
        out[:, 1:] = (out[:, 1:] - self.low) / self.width
        if clip:
            out[:, 1:] = np.clip(out[:, 1:], 0.0, 1.0)
        return out

    def from_unit(self, U: np.ndarray) -> np.ndarray:
        """The search's coordinates as model inputs (inside the box)."""
        out = np.array(U, dtype=np.float64, copy=True)
        out[..., 1:] = self.low + np.clip(out[..., 1:], 0.0, 1.0) * self.width
        return out

    def wrap(self, acqf: Any, tkw: dict[str, Any]) -> Any:
        """``acqf`` of model inputs as a function of the search's coordinates, with its
        closed-form ``value_and_grad`` (``acquisition.Acquisition``) carried over."""
        if acqf is None:
            return None
        import torch

        kind = InBox if getattr(acqf, "value_and_grad", None) is None else InBoxWithGradient
        return kind(acqf, torch.as_tensor(self.low, **tkw), torch.as_tensor(self.width, **tkw))

    def describe(self) -> dict[str, Any]:
        """What the ask's info says of it (in the unit box of the model inputs)."""
        return {
            "trust_region": {
                "side": round(self.side, 6),
                "low": [round(float(v), 6) for v in self.low],
                "high": [round(float(v), 6) for v in self.high],
                "volume": float(np.prod(self.width)),
            }
        }


class InBox:
    """An acquisition of model inputs seen from the trust region's coordinates: spec
    column j is ``low[j] + u[j] * width[j]``, so its gradient there is ``width[j]``
    times the acquisition's."""

    def __init__(self, acqf: Any, low: torch.Tensor, width: torch.Tensor) -> None:
        self.acqf, self.low, self.width = acqf, low, width

    def points(self, U: torch.Tensor) -> torch.Tensor:
        import torch

        return torch.cat([U[..., :1], self.low + U[..., 1:] * self.width], dim=-1)

    def __call__(self, U: torch.Tensor) -> torch.Tensor:
        return self.acqf(self.points(U))


class InBoxWithGradient(InBox):
    """``InBox`` of an acquisition with a closed-form gradient (``acquisition.Acquisition``),
    which the local searches then take instead of autograd's."""

    def value_and_grad(self, U: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        import torch

        values, gradient = self.acqf.value_and_grad(self.points(U))
        return values, torch.cat([gradient[..., :1], gradient[..., 1:] * self.width], dim=-1)


def trust_box(
    centre: np.ndarray, lengthscales: np.ndarray, *, n_train: int, n_observed: int
) -> TrustBox:
    """The trust region around ``centre`` (model inputs, structure index first): its
    side along each spec dimension is ``L * w``, ``w`` the ``lengthscales`` over their
    geometric mean, clipped to the unit box, with ``L`` (at least ``MIN_SIDE``) such
    that the clipped box's volume is the share ``n_train / n_observed`` of the unit box."""
    specs = np.asarray(centre, dtype=np.float64)[1:]
    scales = np.asarray(lengthscales, dtype=np.float64).reshape(-1)
    if len(scales) != len(specs) or not np.all(np.isfinite(scales)) or np.any(scales <= 0):
        scales = np.ones(len(specs))
    weights = scales / np.exp(np.mean(np.log(scales)))
    share = min(1.0, n_train / max(n_observed, 1))

    def box(side: float) -> tuple[np.ndarray, np.ndarray]:
        half = side * weights / 2.0
        return np.clip(specs - half, 0.0, 1.0), np.clip(specs + half, 0.0, 1.0)

    low_side, high_side = MIN_SIDE, 2.0 / float(weights.min())  # the whole box at the top
    for _ in range(60):  # the clipped volume grows with the side: bisect
        middle = (low_side + high_side) / 2.0
        low, high = box(middle)
        low_side, high_side = (
            (middle, high_side) if np.prod(high - low) < share else (low_side, middle)
        )
    side = high_side if share < 1.0 else 2.0 / float(weights.min())
    low, high = box(side)
    high = np.maximum(high, low + 1e-9)  # a box of some width, also at a corner
    return TrustBox(low=low, high=high, side=side)


def spec_lengthscales(model: Any) -> np.ndarray:
    """The fitted spec length scales of a plain box's model (``gpmodel.design_kernel``)."""
    return model.covar_module.spec.lengthscale.detach().cpu().numpy().reshape(-1)
