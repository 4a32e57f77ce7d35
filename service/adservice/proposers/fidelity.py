"""Multi-fidelity proposals: a design and how long it trains, chosen together.

A study whose task declares a fidelity (``task.fidelity``: the learner's train_steps
between ``min`` and ``max``, a cost per step) gets this proposer in place of ``qei``.
It follows BOCA (Kandasamy et al. 2017, "Multi-fidelity Bayesian optimisation with
continuous approximations"):

1. One GP over (design features, fidelity): the design's model inputs (a one-hot tree
   index beside the normalised specs for several trees) and ``s``, the fidelity on a log
   scale from 0 (min) to 1 (max), with an ARD kernel, so the lengthscale of ``s`` learns
   how far a short run's score says what the full run's will be.
2. The design: the best expected improvement *at the top fidelity* over a candidate set
   (scrambled Sobol points and local moves around the designs the model rates best at
   the top), against the best posterior mean at the top among the designs seen.
3. Its fidelity: the cheapest level ``z`` of the study's grid whose posterior standard
   deviation at that design (latent, in units of the observed values' spread) exceeds
   ``THRESHOLD * (cost(z) / cost(max)) ** COST_POWER``, else the top: a design the model
   knows nothing of is first tried short; one whose short runs the model has learned
   (small deviation there) is trained longer, and the one worth it to the full budget.

The start (the study's Sobol points, as ``qei`` deals them) trains at the lowest
fidelity; the last ``FINAL_SHARE`` of a study's trials train at the top, so the study's
best (reported among its top-fidelity trials, docs/method.md) comes from designs the
short runs found. Pending trials count as observed at their fidelity with the posterior
mean (kriging believer), so several workers get different proposals.
"""

from __future__ import annotations

import math
import time
from typing import Any, ClassVar

import numpy as np
from scipy.special import ndtr

from adservice.proposers.base import (
    FidelityHistory,
    FloatArray,
    Proposal,
    ProposalRequest,
    ProposerOptions,
    model_inputs,
)
from adservice.proposers.initial import initial_count, initial_points
from adservice.proposers.qei import _canonical
from adservice.proposers.qei_shared import QEIOptions, limit_threads
from adservice.proposers.simple import derived_seed, scale_to_bounds, sobol_points

THRESHOLD = 1.0
"""BOCA's threshold at the top fidelity's cost, in units of the observed values' spread
(``Standardize``): a level is chosen where the model's deviation there exceeds it scaled
by the cost ratio. About the latent deviation left after one noisy run at a design, so a
design run once at a level moves up when it is chosen again."""
COST_POWER = 0.5
"""How fast the threshold falls with a level's cost (BOCA's ``q``): at a quarter of the
top's cost, half the top's threshold."""
FINAL_SHARE = 0.2
"""The share of a study's trials (at least one) that train at the top fidelity at its end."""
SOBOL_CANDIDATES = 1024
LOCAL_CANDIDATES = 64
"""Candidates around each of the ``LOCAL_CENTRES`` designs rated best at the top."""
LOCAL_CENTRES = 4
LOCAL_STEP = 0.1
"""The local moves' standard deviation, a share of each coordinate's range."""


def threshold(history: FidelityHistory) -> FloatArray:
    """BOCA's threshold at each level of the grid (the top's is never used)."""
    return THRESHOLD * (history.cost / history.cost[-1]) ** COST_POWER


def choose_level(deviations: FloatArray, history: FidelityHistory) -> int:
    """The cheapest level whose deviation exceeds its threshold; else the top."""
    gamma = threshold(history)
    for level in range(len(history.grid) - 1):
        if deviations[level] > gamma[level]:
            return level
    return len(history.grid) - 1


def final(history: FidelityHistory, n_issued: int, offset: int) -> bool:
    """Whether the ask's proposal ``offset`` is among the study's last ``FINAL_SHARE`` of
    trials (at least its last one), which train at the top fidelity."""
    if history.remaining is None:
        return False
    total = history.remaining + n_issued
    return history.remaining - offset <= max(1, math.ceil(FINAL_SHARE * total))


def design_features(Z: np.ndarray, request: ProposalRequest) -> np.ndarray:
    """Model inputs ``[tree index, u]`` as the GP's design features: ``u`` alone for one
    tree, a one-hot tree index beside it for several."""
    structure = request.structure
    if structure is None or structure.n_structures == 1:
        return Z[:, 1:]
    onehot = np.eye(structure.n_structures)[Z[:, 0].astype(np.int64)]
    return np.column_stack([onehot, Z[:, 1:]])


def log_expected_improvement(mean: np.ndarray, sd: np.ndarray, best: float) -> np.ndarray:
    """log EI of a Gaussian (mean, sd) over ``best``: ``log sd + log h(z)`` with
    ``h(z) = z Phi(z) + phi(z)``, its tail ``phi(z) / z**2`` where ``h`` underflows."""
    sd = np.maximum(sd, 1e-12)
    z = (mean - best) / sd
    log_phi = -0.5 * z**2 - 0.5 * math.log(2 * math.pi)
    with np.errstate(divide="ignore", invalid="ignore"):
        h = z * ndtr(z) + np.exp(log_phi)
        log_h = np.where(z > -5.0, np.log(np.maximum(h, 1e-300)), log_phi - 2 * np.log(-z))
    return np.log(sd) + log_h


class FidelityProposer:
    """BOCA over the study's fidelity grid (the module's docstring)."""

    name: ClassVar[str] = "qei"
    needs_history: ClassVar[bool] = True
    multi_objective: ClassVar[bool] = False
    constrained: ClassVar[bool] = False
    options_model: ClassVar[type[ProposerOptions]] = QEIOptions
    """A fidelity study names ``qei``: its options are checked as qei's (and unused)."""

    def propose(self, request: ProposalRequest) -> Proposal:
        history = request.fidelities
        if history is None:
            raise ValueError("a multi-fidelity proposal needs the study's fidelities")
        bounds = np.asarray(request.bounds, dtype=np.float64)
        count = request.count
        rows: list[np.ndarray] = []
        info: list[dict[str, Any]] = []
        n_start = min(max(initial_count(request) - request.n_issued, 0), count)
        if n_start:
            top = len(history.grid) - 1
            for offset, row in enumerate(initial_points(request, bounds, n_start)):
                level = top if final(history, request.n_issued, offset) else 0
                rows.append(row)
                info.append(
                    self._info(
                        history, level, "sobol-initial", sobol_index=request.n_issued + offset
                    )
                )
        if n_start < count:
            model_rows, model_info = self._model_batch(
                request, history, bounds, count - n_start, np.array(rows).reshape(-1, request.dim)
            )
            rows.extend(model_rows)
            info.extend(model_info)
        return Proposal(candidates=_canonical(np.array(rows), bounds, request), info=info)

    @staticmethod
    def _info(history: FidelityHistory, level: int, method: str, **more: Any) -> dict[str, Any]:
        return {
            "proposer": "fidelity",
            "method": method,
            "fidelity": int(history.grid[level]),
            "fidelity_max": int(history.grid[-1]),
            **more,
        }

    def _model_batch(
        self,
        request: ProposalRequest,
        history: FidelityHistory,
        bounds: np.ndarray,
        q: int,
        started: np.ndarray,
    ) -> tuple[list[np.ndarray], list[dict[str, Any]]]:
        import torch
        from botorch.fit import fit_gpytorch_mll
        from botorch.models import SingleTaskGP
        from botorch.models.transforms.outcome import Standardize
        from gpytorch.mlls import ExactMarginalLogLikelihood

        limit_threads(torch)  # one intra-op thread, as qei: small matrices on shared cores
        started_at = time.process_time()
        finite = np.isfinite(request.y)
        X, y = request.X[finite], request.y[finite]
        observed = history.observed[finite]
        if len(y) < 2 or np.ptp(y) == 0.0:
            return self._fallback(request, history, bounds, started, q, "too few distinct values")
        # pending points, and this ask's start points, count as observed at the mean
        believed = np.vstack([request.pending, started]) if len(started) else request.pending
        believed_steps = np.concatenate([history.pending, np.full(len(started), history.grid[0])])
        torch.manual_seed(derived_seed(request.seed, request.n_issued))
        train_x = self._inputs(X, observed, request, bounds, history)
        spread = float(np.std(y)) or 1.0
        tx = torch.as_tensor(train_x, dtype=torch.float64)
        ty = torch.as_tensor(y[:, None], dtype=torch.float64)
        model: Any = SingleTaskGP(tx, ty, outcome_transform=Standardize(m=1))
        try:
            fit_gpytorch_mll(ExactMarginalLogLikelihood(model.likelihood, model))
        except Exception as error:  # a fit that fails proposes from the start's sequence
            return self._fallback(request, history, bounds, started, q, f"fit failed: {error}")
        model.eval()

        def posterior(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            with torch.no_grad():
                post = model.posterior(torch.as_tensor(points, dtype=torch.float64))
                mean = post.mean.squeeze(-1).numpy()
                sd = post.variance.clamp_min(0).sqrt().squeeze(-1).numpy()
            return mean, sd

        def condition(points: np.ndarray) -> None:
            nonlocal model
            if not len(points):
                return
            mean, _ = posterior(points)
            with torch.no_grad():
                model = model.condition_on_observations(
                    torch.as_tensor(points, dtype=torch.float64),
                    torch.as_tensor(mean[:, None], dtype=torch.float64),
                )

        condition(self._inputs(believed, believed_steps, request, bounds, history))
        rng = np.random.default_rng(derived_seed(request.seed, request.n_issued, 61))
        rows: list[np.ndarray] = []
        infos: list[dict[str, Any]] = []
        at_top = np.full(len(X), history.grid[-1])
        top_observed = self._inputs(X, at_top, request, bounds, history)
        for offset in range(len(started), len(started) + q):
            at_end = final(history, request.n_issued, offset)
            best = float(np.max(posterior(top_observed)[0]))
            candidates = self._candidates(request, bounds, rng, X, posterior, history)
            tops = np.full(len(candidates), history.grid[-1])
            top = self._inputs(candidates, tops, request, bounds, history)
            mean, sd = posterior(top)
            score = log_expected_improvement(mean, sd, best)
            chosen = int(np.argmax(score))
            design = candidates[chosen]
            grid_inputs = self._inputs(
                np.repeat(design[None, :], len(history.grid), axis=0),
                history.grid,
                request,
                bounds,
                history,
            )
            _, deviations = posterior(grid_inputs)
            deviations = deviations / spread
            level = len(history.grid) - 1 if at_end else choose_level(deviations, history)
            rows.append(design)
            infos.append(
                self._info(
                    history,
                    level,
                    "boca-final" if at_end else "boca",
                    log_ei=round(float(score[chosen]), 4),
                    deviations=[round(float(d), 4) for d in deviations],
                    thresholds=[round(float(g), 4) for g in threshold(history)],
                    cpu_s=round(time.process_time() - started_at, 3),
                )
            )
            condition(grid_inputs[level : level + 1])  # the batch's next one sees it pending
        return rows, infos

    def _inputs(
        self,
        X: np.ndarray,
        steps: np.ndarray,
        request: ProposalRequest,
        bounds: np.ndarray,
        history: FidelityHistory,
    ) -> np.ndarray:
        features = design_features(model_inputs(X, bounds, request.structure), request)
        return np.column_stack([features, history.level(np.asarray(steps))])

    def _candidates(
        self,
        request: ProposalRequest,
        bounds: np.ndarray,
        rng: np.random.Generator,
        X: np.ndarray,
        posterior: Any,
        history: FidelityHistory,
    ) -> np.ndarray:
        """Sobol points of the box and moves around the designs rated best at the top
        (the tree index kept), inside the spec constraints where a space has any."""
        seed = derived_seed(request.seed, request.n_issued, int(rng.integers(2**31)))
        sobol = scale_to_bounds(sobol_points(request.dim, seed, 0, SOBOL_CANDIDATES), bounds)
        top = self._inputs(X, np.full(len(X), history.grid[-1]), request, bounds, history)
        centres = X[np.argsort(-posterior(top)[0])[:LOCAL_CENTRES]]
        width = bounds[1] - bounds[0]
        moves = rng.normal(0.0, LOCAL_STEP, (len(centres), LOCAL_CANDIDATES, request.dim))
        if request.structure is not None and request.structure.n_structures > 1:
            moves[:, :, 0] = 0.0
        local = (centres[:, None, :] + moves * width).reshape(-1, request.dim)
        candidates = np.clip(np.vstack([sobol, local]), bounds[0], bounds[1])
        if request.spec_polytope is not None:
            inside = request.spec_polytope.holds(candidates)
            if inside.any():
                candidates = candidates[inside]
        return _canonical(candidates, bounds, request)

    def _fallback(
        self,
        request: ProposalRequest,
        history: FidelityHistory,
        bounds: np.ndarray,
        started: np.ndarray,
        q: int,
        reason: str,
    ) -> tuple[list[np.ndarray], list[dict[str, Any]]]:
        """The study's Sobol sequence at the lowest fidelity (the top at its end) while
        the model cannot rank."""
        unit = sobol_points(request.dim, request.seed, request.n_issued + len(started), q)
        rows = list(scale_to_bounds(unit, bounds))
        top, first = len(history.grid) - 1, len(started)
        levels = [top if final(history, request.n_issued, first + i) else 0 for i in range(q)]
        return rows, [
            self._info(history, level, "sobol-fallback", reason=reason) for level in levels
        ]
