"""Maximising an acquisition function over a mixed space: the structure held discrete,
the specs continuous (model inputs ``z = [structure index, u]``, see ``gpmodel``).

1. Raw samples: scrambled Sobol spec vectors, dealt round-robin to the structures,
   every point canonical (unused slots at the pad).
2. Starts (as Optuna's GPSampler and BoTorch's initialiser choose them): the best
   raw sample, the best observed designs (``INCUMBENTS``), and raw samples drawn
   with probability proportional to their acquisition value (a roulette wheel on
   exp(log EI - max)), so some starts explore other basins; with at most
   ``ENUMERATE_LIMIT`` structures, also the best raw sample of every structure, so
   each structure is optimised.
3. Continuous step: L-BFGS-B on the used specs of every start at once, the
   structure fixed (unused slots stay at the pad, out of the optimiser's vector).
4. Discrete step: each optimised point tries every structure with its specs; a
   start that gains by switching is optimised again (``DISCRETE_ROUNDS`` times at
   most). This is what finds good structures among many (``structures: all``).

Told ``structures`` (a subset of the structure indices), every raw sample, start and
switch stays among them, and the best observed designs' specs are also started from
on each of them: the best point found is a design of one of those structures.

A box of typed params (``DiscreteColumns``: ints, stepped floats, categoricals) is
searched the way BoTorch's ``optimize_acqf_mixed_alternating`` searches one: the raw
samples are snapped to valid values (or, when the whole space has no more points
than raw samples, are every point of it), L-BFGS-B moves only the continuous
columns, and a discrete step tries every start's neighbours (an ordinal column one
step down or up, a categorical column every other choice) and moves to the best,
alternating with the continuous step until neither gains (``BOX_ROUNDS`` at most).
The acquisition is this module's own callable (analytic LogEI with Kriging
believers), not a BoTorch acquisition object, hence this loop rather than that
function. With ``taken`` points (observed and pending, noise-free studies) the answer
is the best point found that is not one of them, when there is one: the local
searches' ends first, then the raw samples scored. Every local search can end on an
observed point: on ZDT2 (d = 4, seed 0, two objectives) from the 25th ask on, 12 to 17
of the 21 local searches ended on observed points, most of them started elsewhere, and
while only their ends were candidates 29 of 60 asks were Sobol fallbacks (none since).

Past a ``deadline`` (the ask's time budget) the raw samples not yet scored are left
out, a local search stops at its starts' best points so far, and no discrete round
begins; the best point found is still returned.
"""

from __future__ import annotations

import itertools
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import torch
from scipy.optimize import minimize
from scipy.stats import qmc

if TYPE_CHECKING:
    from adclient.boxspace import BoxEncoding
    from adservice.proposers.base import ChoiceColumns, SpecRegion

# Set once, not per call: catch_warnings swaps the process's filter list, which is not
# safe while other threads propose.
warnings.filterwarnings("ignore", message="The balance properties of Sobol", category=UserWarning)

ENUMERATE_LIMIT = 16
"""With this many structures or fewer, every structure gets a start of its own."""
DISCRETE_ROUNDS = 2
INCUMBENTS = 1
"""Best observed designs started from directly (unless ``maximise`` is told more)."""
BOX_ROUNDS = 8
"""Discrete-then-continuous rounds at most for a box of typed params."""
SCREENED = 64
"""Raw samples scored by the acquisition itself after a ``screen``."""
LOCAL_GTOL = 1e-2
"""A local search stops when no gradient of log EI (per unit of a spec's range) exceeds
this: moving a spec by 1% of its range then changes EI by about 0.01%. GPSampler stops
its local searches at the same gradient in length-scale units."""
TAKEN_TOL = 1e-6
"""A candidate closer than this (max-norm, model inputs) to an observed or pending point
is that point again: the search answers another where it found one, and qei replaces
one it could not avoid by a Sobol point (``reason: duplicate candidate``). One bound
for both, so no candidate the search calls fresh is one qei calls a duplicate; a search
in other coordinates (a trust region's unit box) passes it per column in its own
(``maximise``'s ``taken_tol``)."""
_CHUNK = 1024


class OutOfTime(Exception):
    """Raised inside an optimiser's objective to stop it at the deadline."""


def past(deadline: float | None) -> bool:
    return deadline is not None and time.monotonic() > deadline


@dataclass(frozen=True)
class DiscreteColumns:
    """A typed box's discrete columns in model-input units (``u``, the unit box of the
    encoded bounds): snapping and one-step moves, through its ``BoxEncoding``."""

    box: BoxEncoding
    low: np.ndarray
    width: np.ndarray

    def _encoded(self, U: np.ndarray) -> np.ndarray:
        return self.low + U * self.width

    def _unit(self, X: np.ndarray) -> np.ndarray:
        return (X - self.low) / self.width

    def snap(self, U: np.ndarray) -> np.ndarray:
        return self._unit(self.box.snap(self._encoded(U)))

    def moves(self, U: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Every snapped row's neighbours (one discrete column changed by one step, or
        to another choice) and the row each came from."""
        X = self.box.snap(self._encoded(U))
        variants, owners = [], []
        for column in self.box.ordinal:
            for shifted in self.box.neighbours(X, column):
                keep = np.isfinite(shifted)
                moved = X[keep].copy()
                moved[:, column] = shifted[keep]
                variants.append(moved)
                owners.append(np.flatnonzero(keep))
        for column, count in self.box.categorical.items():
            for choice in range(count):
                keep = X[:, column] != choice
                moved = X[keep].copy()
                moved[:, column] = choice
                variants.append(moved)
                owners.append(np.flatnonzero(keep))
        if not variants:
            return U[:0], np.zeros(0, dtype=np.int64)
        return self._unit(np.concatenate(variants)), np.concatenate(owners)

    def every_point(self) -> np.ndarray:
        """Each point of a space with no continuous column (small: see ``maximise``)."""
        columns = []
        for i, param in enumerate(self.box.params):
            if i in self.box.categorical:
                columns.append(np.arange(self.box.categorical[i], dtype=np.float64))
            else:
                assert param.low is not None and param.high is not None
                step = float(param.step or 1)
                values = np.arange(param.low, param.high + step / 2, step, dtype=np.float64)
                columns.append(np.log(values) if param.log else values)
        grid = np.array(list(itertools.product(*columns)), dtype=np.float64)
        return self._unit(self.box.snap(grid))


@dataclass(frozen=True)
class MixedDomain:
    """Which spec slots each structure uses (S x p), the value of the others, and a
    typed box's discrete columns (None: every slot continuous)."""

    used: np.ndarray
    pad: float
    discrete: DiscreteColumns | None = None
    choices: tuple[ChoiceColumns, ...] = ()
    """Catalogue choices: their columns snap to the nearest component."""
    spec_width: np.ndarray | None = None
    """Each slot's physical width, so a choice's nearest component is measured in its
    catalogue's own coordinates, as decoding measures it."""

    @property
    def n_structures(self) -> int:
        return int(self.used.shape[0])

    @property
    def free(self) -> np.ndarray:
        """Which spec slots a continuous optimiser may move."""
        if self.discrete is None:
            return np.ones(self.used.shape[1], dtype=bool)
        return self.discrete.box.continuous

    def canonical(self, Z: np.ndarray) -> np.ndarray:
        index = Z[:, 0].astype(np.int64)
        specs = np.where(self.used[index], Z[:, 1:], self.pad)
        if self.discrete is not None:
            specs = self.discrete.snap(specs)
        for choice in self.choices:
            specs = self._snap_choice(specs, choice)
        return np.column_stack([Z[:, 0], specs])

    def _snap_choice(self, specs: np.ndarray, choice: ChoiceColumns) -> np.ndarray:
        columns = list(choice.columns)
        scale = np.ones(len(columns)) if self.spec_width is None else self.spec_width[columns]
        gaps = (specs[:, None, columns] - choice.points[None, :, :]) * scale
        nearest = np.argmin((gaps**2).sum(axis=2), axis=1)
        specs = specs.copy()
        specs[:, columns] = choice.points[nearest]
        return specs


Acquisition = Callable[[torch.Tensor], torch.Tensor]
"""b x 1 x D model inputs -> b values. One that also has ``value_and_grad`` (b x D ->
values, their gradient with respect to the inputs) is searched through it instead of
autograd (``posterior.LogEI``); one whose ``on_arrays`` is not None is scored and
searched through that instead, on NumPy arrays (``posterior.OnArrays``): the same
values and gradients, without a tensor per operation."""


@dataclass(frozen=True)
class Optimum:
    z: np.ndarray
    value: float
    structures_switched: int


def _evaluate(
    acqf: Acquisition, Z: np.ndarray, tkw: dict, deadline: float | None = None
) -> np.ndarray:
    """Values at the rows of Z; past ``deadline``, the chunks after the first are -inf."""
    out = np.full(len(Z), -np.inf)
    arrays = getattr(acqf, "on_arrays", None)
    with torch.no_grad():
        for start in range(0, len(Z), _CHUNK):
            if start and past(deadline):
                break
            if arrays is not None:
                out[start : start + _CHUNK] = arrays.values(Z[start : start + _CHUNK])
                continue
            chunk = torch.as_tensor(Z[start : start + _CHUNK], **tkw).unsqueeze(1)
            out[start : start + _CHUNK] = acqf(chunk).detach().cpu().numpy().reshape(-1)
    return np.where(np.isfinite(out), out, -np.inf)


def raw_samples(
    domain: MixedDomain,
    count: int,
    rng: np.random.Generator,
    structures: np.ndarray | None = None,
) -> np.ndarray:
    """Sobol spec vectors dealt round-robin to the structures (``structures``: to those
    alone), canonical; every point of a typed box that has no more points than
    ``count``."""
    box = domain.discrete.box if domain.discrete is not None else None
    if domain.discrete is not None and box is not None and (box.n_points or count + 1) <= count:
        specs = domain.discrete.every_point()
        return np.column_stack([np.zeros(len(specs)), specs])
    p = domain.used.shape[1]
    specs = qmc.Sobol(p, scramble=True, rng=rng).random(count) if p else np.zeros((count, 0))
    dealt = np.arange(domain.n_structures) if structures is None else structures
    index = dealt[(np.arange(count) + rng.integers(len(dealt))) % len(dealt)]
    return domain.canonical(np.column_stack([index, specs]))


def starts(
    raw: np.ndarray, values: np.ndarray, count: int, rng: np.random.Generator, enumerate_all: bool
) -> list[int]:
    """Indices of the raw samples to start from (see the module docstring)."""
    best = int(np.argmax(values))
    chosen = [best]
    if enumerate_all:
        structure = raw[:, 0].astype(np.int64)
        order = np.argsort(-values, kind="stable")
        for s in np.unique(structure):
            chosen.append(int(order[structure[order] == s][0]))
    weights = np.exp(np.where(np.isfinite(values), values - values[best], -np.inf))
    weights[chosen] = 0.0
    extra = min(count - len(chosen), int(np.count_nonzero(weights > 0)))
    if extra > 0:
        picked = rng.choice(len(raw), size=extra, replace=False, p=weights / weights.sum())
        chosen += [int(i) for i in picked]
    return list(dict.fromkeys(chosen))


def _local(
    acqf: Acquisition,
    domain: MixedDomain,
    starts: np.ndarray,
    maxiter: int,
    tkw: dict,
    deadline: float | None = None,
    region: SpecRegion | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """L-BFGS-B on every start's used specs at once (the others stay at the pad, out of
    the optimiser's vector); (points, values). Past ``deadline``, each start's best
    point evaluated so far. With a ``region``, each end moved to the nearest point
    inside it."""
    b, p = starts.shape[0], starts.shape[1] - 1
    used = domain.used[starts[:, 0].astype(np.int64)] & domain.free
    if p == 0 or not used.any():
        return starts, _evaluate(acqf, starts, tkw)
    full = torch.as_tensor(starts, **tkw)
    mask = torch.as_tensor(np.column_stack([np.zeros(b, dtype=bool), used]), device=full.device)
    initial = np.clip(starts[:, 1:][used], 0.0, 1.0)
    owner = np.repeat(np.arange(b), used.sum(axis=1))  # the start of each free value
    best_free, best_values = initial.copy(), np.full(b, -np.inf)
    evaluations = 0

    arrays = getattr(acqf, "on_arrays", None)
    points_np = starts.copy()

    def track(current: np.ndarray, free: np.ndarray) -> None:
        """Each start's best point so far (a deadline stops the search)."""
        better = current > best_values
        best_free[better[owner]] = free[better[owner]]
        best_values[better] = current[better]

    def on_arrays(free: np.ndarray) -> tuple[float, np.ndarray]:
        assert arrays is not None
        points_np[:, 1:][used] = free
        values, by_point = arrays.with_gradient(points_np)
        loss = -values.sum()
        if not np.isfinite(loss):
            return 1e10, np.zeros_like(free)
        if deadline is not None:
            track(values, free)
        return float(loss), -by_point[:, 1:][used]

    def objective(free: np.ndarray) -> tuple[float, np.ndarray]:
        nonlocal evaluations
        if evaluations and past(deadline):
            raise OutOfTime
        evaluations += 1
        if arrays is not None:
            return on_arrays(free)
        closed = getattr(acqf, "value_and_grad", None)
        values_t = torch.as_tensor(free, **tkw).requires_grad_(closed is None)
        points = full.masked_scatter(mask, values_t)
        if closed is not None:
            values, by_point = closed(points)
        else:
            values = acqf(points.unsqueeze(1))
        loss = -values.sum()
        if not torch.isfinite(loss):
            return 1e10, np.zeros_like(free)
        if deadline is not None:
            track(values.detach().cpu().numpy().reshape(-1), free)
        if closed is not None:
            gradient = -by_point[mask]
        else:
            (gradient,) = torch.autograd.grad(loss, values_t)
        return float(loss.item()), gradient.detach().cpu().numpy().astype(np.float64)

    try:
        found = minimize(
            objective,
            initial,
            jac=True,
            method="L-BFGS-B",
            bounds=[(0.0, 1.0)] * int(used.sum()),
            options={"maxiter": maxiter, "gtol": LOCAL_GTOL},
        ).x
    except OutOfTime:
        found = best_free
    points = starts.copy()
    points[:, 1:][used] = np.clip(found, 0.0, 1.0)
    if domain.choices:
        points = domain.canonical(points)
    if region is not None:
        points = region.inside(points)
    return points, _evaluate(acqf, points, tkw)


def maximise(
    acqf: Acquisition,
    domain: MixedDomain,
    *,
    raw_count: int,
    num_restarts: int,
    maxiter: int,
    seed: int,
    incumbents: np.ndarray,
    tkw: dict,
    deadline: float | None = None,
    taken: np.ndarray | None = None,
    taken_tol: float | np.ndarray = TAKEN_TOL,
    screen: Acquisition | None = None,
    n_incumbents: int = INCUMBENTS,
    region: SpecRegion | None = None,
    structures: np.ndarray | None = None,
) -> Optimum:
    """The best point found, not one of ``taken`` if any other was found (see the
    module docstring): a point is taken when it lies within ``taken_tol`` of a taken
    point in every column (a scalar, or one per column of ``z``). ``screen``: a cheaper
    estimate of ``acqf`` (a Monte Carlo acquisition with fewer draws) that scores the
    raw samples and picks the starts; then only the ``SCREENED`` best raw samples are
    scored with ``acqf`` itself. ``region``: spec constraints; the raw samples are the
    feasible ones (topped up with the nearest feasible points to others), and every
    local search's end is moved to the nearest feasible point, so the best point found
    satisfies them.
    ``structures``: the structures the answer may have (see the module docstring)."""
    rng = np.random.default_rng(seed)
    allowed = np.arange(domain.n_structures) if structures is None else structures
    S = len(allowed)
    raw = raw_samples(domain, raw_count, rng, structures)
    if region is not None:
        raw = _feasible_raw(raw, region, num_restarts)
    values = raw_values = _evaluate(screen or acqf, raw, tkw, deadline)
    chosen = starts(raw, values, num_restarts, rng, 1 < S <= ENUMERATE_LIMIT)
    best_known = incumbents[:n_incumbents]
    if structures is not None:
        best_known = np.repeat(best_known, S, axis=0)
        best_known[:, 0] = np.tile(allowed, n_incumbents)[: len(best_known)]
    initial = np.concatenate([raw[chosen], domain.canonical(best_known)])
    if screen is not None:
        best_raw = np.argsort(-raw_values, kind="stable")[:SCREENED]
        raw, raw_values = raw[best_raw], _evaluate(acqf, raw[best_raw], tkw)
    points, values = _local(acqf, domain, initial, maxiter, tkw, deadline, region)
    switched = 0
    for _ in range(DISCRETE_ROUNDS if S > 1 else 0):
        if past(deadline):
            break
        variants = np.repeat(points, S, axis=0)
        variants[:, 0] = np.tile(allowed, len(points))
        variants = domain.canonical(variants)
        scores = _evaluate(acqf, variants, tkw).reshape(len(points), S)
        best = scores.argmax(axis=1)
        better = scores[np.arange(len(points)), best] > values + 1e-9 * (1 + np.abs(values))
        if not better.any():
            break
        switched += int(better.sum())
        moved = variants.reshape(len(points), S, -1)[better, best[better]]
        points[better], values[better] = _local(acqf, domain, moved, maxiter, tkw, deadline, region)
    if domain.discrete is not None:
        points, values = _discrete_rounds(acqf, domain, points, values, maxiter, tkw, deadline)
    points, values = np.concatenate([points, raw]), np.concatenate([values, raw_values])
    order = np.argsort(-values, kind="stable")
    top = int(order[0])
    if taken is not None and len(taken):
        fresh = (int(i) for i in order if not near_any(taken, points[i], taken_tol))
        top = next(fresh, top)
    return Optimum(z=points[top], value=float(values[top]), structures_switched=switched)


def _feasible_raw(raw: np.ndarray, region: SpecRegion, at_least: int) -> np.ndarray:
    """The raw samples inside the spec constraints; when fewer than ``at_least`` are,
    the nearest feasible points to the first others make up the number."""
    inside = region.holds(raw)
    kept = raw[inside]
    missing = at_least - len(kept)
    if missing > 0:
        kept = np.concatenate([kept, region.inside(raw[~inside][:missing])])
    return kept


def near_any(points: np.ndarray, point: np.ndarray, tol: float | np.ndarray) -> bool:
    """Whether some row of ``points`` is within ``tol`` of ``point`` in every column:
    for a scalar, ``nearest_distance(points, point) < tol``."""
    return bool(np.any(np.all(np.abs(points - point) < tol, axis=1)))


def nearest_distance(points: np.ndarray, point: np.ndarray) -> float:
    """Max-norm distance from ``point`` to the nearest row of ``points`` (inf if none)."""
    if len(points) == 0:
        return float("inf")
    return float(np.min(np.max(np.abs(points - point), axis=1)))


def _discrete_rounds(
    acqf: Acquisition,
    domain: MixedDomain,
    points: np.ndarray,
    values: np.ndarray,
    maxiter: int,
    tkw: dict,
    deadline: float | None,
) -> tuple[np.ndarray, np.ndarray]:
    """A typed box's discrete steps: each point moves to its best neighbour while that
    gains, its continuous columns optimised again after each move."""
    assert domain.discrete is not None
    points, values = points.copy(), values.copy()
    for _ in range(BOX_ROUNDS):
        if past(deadline):
            break
        moves, owners = domain.discrete.moves(points[:, 1:])
        if len(moves) == 0:
            break
        scores = _evaluate(acqf, np.column_stack([np.zeros(len(moves)), moves]), tkw)
        best = np.full(len(points), -np.inf)
        pick = np.full(len(points), -1)
        for index in np.argsort(scores, kind="stable"):  # the best move of each owner last
            best[owners[index]], pick[owners[index]] = scores[index], index
        better = best > values + 1e-9 * (1 + np.abs(values))
        if not better.any():
            break
        moved = np.column_stack([np.zeros(int(better.sum())), moves[pick[better]]])
        points[better], values[better] = _local(acqf, domain, moved, maxiter, tkw, deadline)
    return points, values
