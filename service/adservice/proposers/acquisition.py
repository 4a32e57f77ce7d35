"""Maximising an acquisition function over a mixed space: the structure held discrete,
the specs continuous (model inputs ``z = [structure index, u]``, see ``gpmodel``).

1. Raw samples: scrambled Sobol spec vectors, dealt round-robin to the structures,
   plus the best observed designs and small perturbations of them (the local
   search of Optuna's GPSampler); every point canonical (unused slots at the pad).
2. Starts: the best raw samples; with at most ``ENUMERATE_LIMIT`` structures, the
   best raw sample of every structure and the best few overall, so each structure
   is optimised.
3. Continuous step: L-BFGS-B on the used specs of every start at once, the
   structure fixed (unused slots are pinned by equal bounds).
4. Discrete step: each optimised point tries every structure with its specs; a
   start that gains by switching is optimised again (``DISCRETE_ROUNDS`` times at
   most). This is what finds good structures among many (``structures: all``).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
from scipy.optimize import minimize
from scipy.stats import qmc
from threadpoolctl import threadpool_limits

ENUMERATE_LIMIT = 16
"""With this many structures or fewer, every structure gets a start of its own."""
DISCRETE_ROUNDS = 2
INCUMBENTS = 3
PERTURBATIONS = 12
"""Perturbed copies of each incumbent among the raw samples (half at each scale)."""
PERTURBATION_SCALES = (0.02, 0.1)
_CHUNK = 1024


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
    n_starts: int
    structures_switched: int


def _evaluate(acqf: Acquisition, Z: np.ndarray, tkw: dict) -> np.ndarray:
    values = []
    with torch.no_grad():
        for start in range(0, len(Z), _CHUNK):
            chunk = torch.as_tensor(Z[start : start + _CHUNK], **tkw).unsqueeze(1)
            values.append(acqf(chunk).detach().cpu().numpy().reshape(-1))
    out = np.concatenate(values) if values else np.zeros(0)
    return np.where(np.isfinite(out), out, -np.inf)


def raw_samples(domain: MixedDomain, count: int, seed: int, incumbents: np.ndarray) -> np.ndarray:
    """Sobol points dealt to the structures, plus incumbents and their perturbations."""
    p = domain.used.shape[1]
    rng = np.random.default_rng(seed)
    if p:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # counts not a power of two
            specs = qmc.Sobol(p, scramble=True, rng=rng).random(count)
    else:
        specs = np.zeros((count, 0))
    index = (np.arange(count) + rng.integers(domain.n_structures)) % domain.n_structures
    points = [np.column_stack([index, specs])]
    for z in incumbents[:INCUMBENTS]:
        for scale in PERTURBATION_SCALES:
            noise = rng.normal(0.0, scale, size=(PERTURBATIONS // 2, p))
            moved = np.clip(z[1:] + noise, 0.0, 1.0)
            points.append(np.column_stack([np.full(len(moved), z[0]), moved]))
        points.append(z[None, :])
    return domain.canonical(np.concatenate(points, axis=0))


def _local(
    acqf: Acquisition, domain: MixedDomain, starts: np.ndarray, maxiter: int, tkw: dict
) -> tuple[np.ndarray, np.ndarray]:
    """L-BFGS-B on every start's used specs at once (the others stay at the pad, out of
    the optimiser's vector); (points, values)."""
    b, p = starts.shape[0], starts.shape[1] - 1
    used = domain.used[starts[:, 0].astype(np.int64)]
    if p == 0 or not used.any():
        return starts, _evaluate(acqf, starts, tkw)
    full = torch.as_tensor(starts, **tkw)
    mask = torch.as_tensor(np.column_stack([np.zeros(b, dtype=bool), used]), device=full.device)

    def objective(free: np.ndarray) -> tuple[float, np.ndarray]:
        values_t = torch.as_tensor(free, **tkw).requires_grad_(True)
        points = full.masked_scatter(mask, values_t)
        loss = -acqf(points.unsqueeze(1)).sum()
        if not torch.isfinite(loss):
            return 1e10, np.zeros_like(free)
        (gradient,) = torch.autograd.grad(loss, values_t)
        return float(loss.item()), gradient.detach().cpu().numpy().astype(np.float64)

    with threadpool_limits(limits=1):  # BLAS threads inside L-BFGS-B only contend here
        result = minimize(
            objective,
            np.clip(starts[:, 1:][used], 0.0, 1.0),
            jac=True,
            method="L-BFGS-B",
            bounds=[(0.0, 1.0)] * int(used.sum()),
            options={"maxiter": maxiter},
        )
    points = starts.copy()
    points[:, 1:][used] = np.clip(result.x, 0.0, 1.0)
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
) -> Optimum:
    """The best point found (see the module docstring)."""
    raw = raw_samples(domain, raw_count, seed, incumbents)
    values = _evaluate(acqf, raw, tkw)
    order = np.argsort(-values, kind="stable")
    S = domain.n_structures
    enumerate_all = 1 < S <= ENUMERATE_LIMIT
    chosen = list(order[: max(num_restarts - S, 2) if enumerate_all else num_restarts])
    if enumerate_all:
        structure = raw[:, 0].astype(np.int64)
        for s in range(S):
            members = order[structure[order] == s]
            if len(members):
                chosen.append(members[0])
    chosen = list(dict.fromkeys(int(i) for i in chosen))
    points, values = _local(acqf, domain, raw[chosen], maxiter, tkw)
    switched = 0
    for _ in range(DISCRETE_ROUNDS if S > 1 else 0):
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
        points[better], values[better] = _local(acqf, domain, moved, maxiter, tkw)
    top = int(np.argmax(values))
    return Optimum(
        z=points[top], value=float(values[top]), n_starts=len(chosen), structures_switched=switched
    )
