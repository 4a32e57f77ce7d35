"""SciPy's Nelder-Mead, driven through ask/tell by replaying the study's history.

Nelder-Mead is sequential and SciPy's implementation is a closed loop, so each ask
re-runs ``scipy.optimize.minimize(method="Nelder-Mead")`` from the same start with
an objective that *looks up* every point it is asked for in the history. The first
point it asks for that the history lacks is the next point to evaluate: the
objective raises :class:`NeedEvaluation` there and the replay stops. SciPy's
arithmetic is deterministic, so a replay reaches the exact same floating-point
vectors every time and the look-up (max-norm tolerance 1e-9 in the unit box)
always matches the trials it issued earlier. Nothing is stored between asks.

Details:

- The search runs in the unit box (bounds clipped by SciPy's bounded variant). The
  start is point 0 of the study's scrambled Sobol sequence (so the seed matters);
  the initial simplex adds ``initial_step`` (option, default 0.1 of each side, at
  most 0.5) along each axis, mirrored inward at the upper bound. ``n_initial`` is
  not used: the simplex is the initial design.
- Values: the objective is ``-y`` (y is oriented to be maximised). A failed trial
  counts as ``+inf`` (worse than anything), a fixed value, so replays stay stable.
  A point told more than once uses its first value, also for stability.
- Convergence (simplex smaller than 1e-6 of the box) restarts the method from the
  best point with the initial step; after 20 restarts the proposer falls back to
  the Sobol sequence.
- Pending points and batches: if the replay stops at a point that is pending (or
  was already chosen for this batch), the simplex cannot move until it is scored.
  The proposer then *speculates*: it replays again with a lie for that point's value
  and takes the first unseen point the method would ask for next. Lies are tried
  best-first: the median of the observed values (a constant liar) first, then an
  optimistic lie (better than the best: NM would ask for the expansion point) and
  a pessimistic one (worse than the worst: NM would ask for the inside contraction
  or shrink). Branches with fewer non-median lies come first, then shallower ones.
  Every candidate is thus a point Nelder-Mead itself asks for on a plausible
  continuation; if the lie proves right the replay later finds it already scored.
  If no branch yields a new point within the replay budget, the candidate is the
  study's Sobol point ``n_issued + i`` and its info says so.
- Typed params (``request.box``: ints, steps, categoricals): the simplex moves in the
  continuous box and each point it asks for is scored as the params it rounds to
  (``BoxEncoding.snap``): the look-up, the pending check and the candidate are the
  snapped point, so two simplex points that round alike share one evaluation and a
  pending rounded point is speculated over like any other. A categorical is thus
  searched as its choices' indices, an order Nelder-Mead cannot avoid assuming.
"""

from __future__ import annotations

import heapq
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from pydantic import Field
from scipy.optimize import minimize

from adservice.proposers.base import Proposal, ProposalRequest, ProposerOptions
from adservice.proposers.simple import scale_to_bounds, sobol_points

_MATCH_TOL = 1e-9
_MAX_RESTARTS = 20
_MAX_REPLAYS_PER_CANDIDATE = 64


class NeedEvaluation(Exception):
    """Raised inside the replay at the first point the history has no value for."""

    def __init__(self, point: np.ndarray) -> None:
        super().__init__("need evaluation")
        self.point = point


@dataclass(frozen=True)
class _Outcome:
    point: np.ndarray | None
    restart: int


class _History:
    """Values (to minimise) by point, matched with a max-norm tolerance."""

    def __init__(self, dim: int) -> None:
        self.points = np.zeros((0, dim))
        self.values = np.zeros(0)

    def add(self, points: np.ndarray, values: np.ndarray) -> None:
        self.points = np.concatenate([self.points, points.reshape(-1, self.points.shape[1])])
        self.values = np.concatenate([self.values, values])

    def find(self, point: np.ndarray) -> int | None:
        if len(self.points) == 0:
            return None
        hits = np.flatnonzero(np.max(np.abs(self.points - point), axis=1) <= _MATCH_TOL)
        return int(hits[0]) if len(hits) else None


def _initial_simplex(x0: np.ndarray, step: float) -> np.ndarray:
    dim = len(x0)
    simplex = np.tile(x0, (dim + 1, 1))
    for i in range(dim):
        simplex[i + 1, i] = x0[i] + step if x0[i] + step <= 1.0 else x0[i] - step
    return simplex


def replay(
    x0: np.ndarray,
    lookup: _History,
    *,
    step: float,
    adaptive: bool,
    snap: Callable[[np.ndarray], np.ndarray] | None = None,
) -> _Outcome:
    """Run Nelder-Mead (with restarts) on looked-up values until it needs a new point;
    ``snap`` maps a point to the one it is scored as (typed params)."""
    dim = len(x0)

    def objective(u: np.ndarray) -> float:
        point = np.array(u, dtype=np.float64) if snap is None else snap(u)
        index = lookup.find(point)
        if index is None:
            raise NeedEvaluation(point)
        return float(lookup.values[index])

    start = np.array(x0, dtype=np.float64)
    for restart in range(_MAX_RESTARTS + 1):
        try:
            with warnings.catch_warnings(), np.errstate(all="ignore"):
                warnings.simplefilter("ignore")
                result = minimize(
                    objective,
                    start,
                    method="Nelder-Mead",
                    bounds=[(0.0, 1.0)] * dim,
                    options={
                        "initial_simplex": _initial_simplex(start, step),
                        "xatol": 1e-6,
                        "fatol": np.inf,
                        "maxiter": 10**9,
                        "maxfev": 10**9,
                        "adaptive": adaptive,
                    },
                )
        except NeedEvaluation as need:
            return _Outcome(point=np.clip(need.point, 0.0, 1.0), restart=restart)
        start = np.clip(np.asarray(result.x, dtype=np.float64), 0.0, 1.0)
    return _Outcome(point=None, restart=_MAX_RESTARTS)


class NelderMeadOptions(ProposerOptions):
    initial_step: float = Field(
        default=0.1,
        gt=0.0,
        le=0.5,
        description="Initial simplex step, a fraction of each side of the box (at most "
        "0.5, so the step inward from any start stays inside the box)",
    )
    adaptive: bool = Field(default=False, description="SciPy's dimension-adapted parameters")


class NelderMeadProposer:
    """Nelder-Mead through ask/tell; speculates with lies while simplex points are pending."""

    name: ClassVar[str] = "nelder-mead"
    needs_history: ClassVar[bool] = True
    multi_objective: ClassVar[bool] = False
    constrained: ClassVar[bool] = False
    options_model: ClassVar[type[ProposerOptions]] = NelderMeadOptions

    def propose(self, request: ProposalRequest) -> Proposal:
        options = NelderMeadOptions.model_validate(request.options)
        dim = request.dim
        bounds = np.asarray(request.bounds, dtype=np.float64)
        span = bounds[1] - bounds[0]
        step = options.initial_step
        adaptive = options.adaptive
        box = request.box
        snap = None
        if box is not None:

            def snap(u: np.ndarray) -> np.ndarray:
                return (box.snap(np.clip(u, 0.0, 1.0) * span + bounds[0]) - bounds[0]) / span

        known = _History(dim)
        X = np.asarray(request.X, dtype=np.float64).reshape(-1, dim)
        y = np.asarray(request.y, dtype=np.float64).reshape(-1)
        finite = np.isfinite(y) & np.all(np.isfinite(X), axis=1)
        known.add((X[finite] - bounds[0]) / span, -y[finite])
        failed = np.asarray(request.failed, dtype=np.float64).reshape(-1, dim)
        failed = failed[np.all(np.isfinite(failed), axis=1)]
        known.add((failed - bounds[0]) / span, np.full(len(failed), np.inf))

        pending = np.asarray(request.pending, dtype=np.float64).reshape(-1, dim)
        blocked = list((pending[np.all(np.isfinite(pending), axis=1)] - bounds[0]) / span)

        finite_values = known.values[np.isfinite(known.values)]
        if len(finite_values):
            low, high = float(finite_values.min()), float(finite_values.max())
            width = max(high - low, 1.0)
            lies = [float(np.median(finite_values)), low - width, high + width]
        else:
            lies = [0.0, -1.0, 1.0]

        x0 = sobol_points(dim, request.seed, 0, 1)[0]
        unit_rows: list[np.ndarray] = []
        info: list[dict[str, Any]] = []
        for i in range(request.count):
            point, details = self._next_point(x0, known, blocked, lies, step, adaptive, snap)
            if point is None:
                index = request.n_issued + i
                point = sobol_points(dim, request.seed, index, 1)[0]
                point = point if snap is None else snap(point)
                details = {
                    "method": "sobol-fallback",
                    "reason": details["reason"],
                    "sobol_index": index,
                }
            unit_rows.append(point)
            blocked.append(point)
            info.append({"proposer": self.name, **details})
        candidates = scale_to_bounds(np.array(unit_rows), bounds)
        return Proposal(candidates=np.clip(candidates, bounds[0], bounds[1]), info=info)

    def _next_point(
        self,
        x0: np.ndarray,
        known: _History,
        blocked: list[np.ndarray],
        lies: list[float],
        step: float,
        adaptive: bool,
        snap: Callable[[np.ndarray], np.ndarray] | None,
    ) -> tuple[np.ndarray | None, dict[str, Any]]:
        """Best-first search over lies for blocked points until NM asks for a new point."""
        # heap entries: (non-median lies, depth, tie-break, ((blocked index, lie index), ...))
        frontier: list[tuple[int, int, int, tuple[tuple[int, int], ...]]] = [(0, 0, 0, ())]
        pushed = 1
        replays = 0
        restart = 0
        while frontier and replays < _MAX_REPLAYS_PER_CANDIDATE:
            _, depth, _, assumed = heapq.heappop(frontier)
            lookup = _History(len(x0))
            lookup.points, lookup.values = known.points, known.values
            if assumed:
                lookup.add(
                    np.array([blocked[b] for b, _ in assumed]),
                    np.array([lies[lie] for _, lie in assumed]),
                )
            outcome = replay(x0, lookup, step=step, adaptive=adaptive, snap=snap)
            replays += 1
            restart = max(restart, outcome.restart)
            if outcome.point is None:
                continue
            hit = _find_blocked(blocked, outcome.point)
            if hit is None:
                details: dict[str, Any] = {"method": "nelder-mead", "restart": outcome.restart}
                if assumed:
                    details["speculative"] = True
                    details["lies"] = [
                        ["median", "optimistic", "pessimistic"][lie] for _, lie in assumed
                    ]
                return outcome.point, details
            for lie in range(len(lies)):
                surprise = sum(1 for _, used in assumed if used) + (1 if lie else 0)
                heapq.heappush(frontier, (surprise, depth + 1, pushed, (*assumed, (hit, lie))))
                pushed += 1
        reason = (
            f"no new Nelder-Mead point after {replays} speculative replays"
            if replays >= _MAX_REPLAYS_PER_CANDIDATE or frontier
            else f"Nelder-Mead converged {restart} times"
        )
        return None, {"reason": reason}


def _find_blocked(blocked: list[np.ndarray], point: np.ndarray) -> int | None:
    for index, other in enumerate(blocked):
        if np.max(np.abs(other - point)) <= _MATCH_TOL:
            return index
    return None
