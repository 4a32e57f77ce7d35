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

Past a ``deadline`` (the ask's time budget) the raw samples not yet scored are left
out, a local search stops at its starts' best points so far, and no discrete round
begins; the best point found is still returned.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
from scipy.optimize import minimize
from scipy.stats import qmc

# Set once, not per call: catch_warnings swaps the process's filter list, which is not
# safe while other threads propose.
warnings.filterwarnings("ignore", message="The balance properties of Sobol", category=UserWarning)

ENUMERATE_LIMIT = 16
"""With this many structures or fewer, every structure gets a start of its own."""
DISCRETE_ROUNDS = 2
INCUMBENTS = 1
"""Best observed designs started from directly."""
_CHUNK = 1024


class OutOfTime(Exception):
    """Raised inside an optimiser's objective to stop it at the deadline."""


def past(deadline: float | None) -> bool:
    return deadline is not None and time.monotonic() > deadline


@dataclass(frozen=True)
class MixedDomain:
    """Which spec slots each structure uses (S x p), and the value of the others."""

    used: np.ndarray
    pad: float

    @property
    def n_structures(self) -> int:
        return int(self.used.shape[0])

    def canonical(self, Z: np.ndarray) -> np.ndarray:
        index = Z[:, 0].astype(np.int64)
        return np.column_stack([Z[:, 0], np.where(self.used[index], Z[:, 1:], self.pad)])


Acquisition = Callable[[torch.Tensor], torch.Tensor]
"""b x 1 x D model inputs -> b values."""


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
    with torch.no_grad():
        for start in range(0, len(Z), _CHUNK):
            if start and past(deadline):
                break
            chunk = torch.as_tensor(Z[start : start + _CHUNK], **tkw).unsqueeze(1)
            out[start : start + _CHUNK] = acqf(chunk).detach().cpu().numpy().reshape(-1)
    return np.where(np.isfinite(out), out, -np.inf)


def raw_samples(domain: MixedDomain, count: int, rng: np.random.Generator) -> np.ndarray:
    """Sobol spec vectors dealt round-robin to the structures, canonical."""
    p = domain.used.shape[1]
    specs = qmc.Sobol(p, scramble=True, rng=rng).random(count) if p else np.zeros((count, 0))
    index = (np.arange(count) + rng.integers(domain.n_structures)) % domain.n_structures
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
) -> tuple[np.ndarray, np.ndarray]:
    """L-BFGS-B on every start's used specs at once (the others stay at the pad, out of
    the optimiser's vector); (points, values). Past ``deadline``, each start's best
    point evaluated so far."""
    b, p = starts.shape[0], starts.shape[1] - 1
    used = domain.used[starts[:, 0].astype(np.int64)]
    if p == 0 or not used.any():
        return starts, _evaluate(acqf, starts, tkw)
    full = torch.as_tensor(starts, **tkw)
    mask = torch.as_tensor(np.column_stack([np.zeros(b, dtype=bool), used]), device=full.device)
    initial = np.clip(starts[:, 1:][used], 0.0, 1.0)
    owner = np.repeat(np.arange(b), used.sum(axis=1))  # the start of each free value
    best_free, best_values = initial.copy(), np.full(b, -np.inf)
    evaluations = 0

    def objective(free: np.ndarray) -> tuple[float, np.ndarray]:
        nonlocal evaluations
        if evaluations and past(deadline):
            raise OutOfTime
        evaluations += 1
        values_t = torch.as_tensor(free, **tkw).requires_grad_(True)
        points = full.masked_scatter(mask, values_t)
        values = acqf(points.unsqueeze(1))
        loss = -values.sum()
        if not torch.isfinite(loss):
            return 1e10, np.zeros_like(free)
        if deadline is not None:
            current = values.detach().cpu().numpy().reshape(-1)
            better = current > best_values
            best_free[better[owner]] = free[better[owner]]
            best_values[better] = current[better]
        (gradient,) = torch.autograd.grad(loss, values_t)
        return float(loss.item()), gradient.detach().cpu().numpy().astype(np.float64)

    try:
        found = minimize(
            objective,
            initial,
            jac=True,
            method="L-BFGS-B",
            bounds=[(0.0, 1.0)] * int(used.sum()),
            options={"maxiter": maxiter},
        ).x
    except OutOfTime:
        found = best_free
    points = starts.copy()
    points[:, 1:][used] = np.clip(found, 0.0, 1.0)
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
) -> Optimum:
    """The best point found (see the module docstring)."""
    rng = np.random.default_rng(seed)
    S = domain.n_structures
    raw = raw_samples(domain, raw_count, rng)
    values = _evaluate(acqf, raw, tkw, deadline)
    chosen = starts(raw, values, num_restarts, rng, 1 < S <= ENUMERATE_LIMIT)
    initial = np.concatenate([raw[chosen], domain.canonical(incumbents[:INCUMBENTS])])
    points, values = _local(acqf, domain, initial, maxiter, tkw, deadline)
    switched = 0
    for _ in range(DISCRETE_ROUNDS if S > 1 else 0):
        if past(deadline):
            break
        variants = np.repeat(points, S, axis=0)
        variants[:, 0] = np.tile(np.arange(S), len(points))
        variants = domain.canonical(variants)
        scores = _evaluate(acqf, variants, tkw).reshape(len(points), S)
        best = scores.argmax(axis=1)
        better = scores[np.arange(len(points)), best] > values + 1e-9 * (1 + np.abs(values))
        if not better.any():
            break
        switched += int(better.sum())
        moved = variants.reshape(len(points), S, -1)[better, best[better]]
        points[better], values[better] = _local(acqf, domain, moved, maxiter, tkw, deadline)
    top = int(np.argmax(values))
    return Optimum(z=points[top], value=float(values[top]), structures_switched=switched)
