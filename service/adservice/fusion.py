"""Representation fusion (docs/method.md, "Representations"): spec distances and
structure similarities fused into one consistent distance.

``fuse_distances`` solves

    minimise   sum over pairs i < j of (f_ij - d_ij)^2
    subject to f_ij >= f_kl + margin   whenever g_ij < g_kl   (consecutive levels)
               f >= 0

either with OSQP (a sparse QP: one auxiliary variable t_l per boundary between
consecutive similarity levels; each pair of the more similar level is bounded above
by t_l, each pair of the next level below by t_l + margin, so the constraint count is
linear in the number of pairs; the ADMM answer is polished in closed form on the
active set it suggests, and f is read off the polished boundaries) or exactly
(``solver="exact"``): with levels sorted by similarity, descending, and each level's
pairs by d ascending, the nonnegative least-squares non-decreasing fit of d (shifted
by the margin per level) is the optimum (Kruskal's primary approach to ties; de Leeuw,
1977), which pool-adjacent-violators computes in O(n). Every OSQP answer is checked
against the exact one (relative objective gap and largest order violation), and
replaced by it when the check fails (``fusion_fallback`` in the diagnostics).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Literal

import numpy as np
import osqp
import scipy.sparse as sp
from scipy.optimize import isotonic_regression

Solver = Literal["osqp", "exact"]

GAP_TOLERANCE = 1e-6
"""Largest relative objective gap an OSQP answer may have before the exact one replaces it."""
VIOLATION_TOLERANCE = 1e-8
"""Largest order (or sign) violation an OSQP answer may have."""
LEVEL_DECIMALS = 12
"""Similarities equal to this many decimals are one level (ties)."""
RHO = 5.0
"""OSQP's ADMM step size, fixed, for distances scaled to at most 1 (tuned on bench/fusion.py)."""


@dataclass(frozen=True)
class PairProblem:
    """The fusion problem over the upper-triangle pairs.

    ``d``: spec distances; ``level``: 0 for the most similar level, rising as
    similarity falls; ``margin``: the gap required between consecutive levels.
    """

    d: np.ndarray
    level: np.ndarray
    n_levels: int
    margin: float

    def objective(self, f: np.ndarray) -> float:
        return float(np.sum((f - self.d) ** 2))


@dataclass(frozen=True)
class FusionCheck:
    objective: float
    exact_objective: float
    relative_gap: float
    max_violation: float

    @property
    def ok(self) -> bool:
        return self.relative_gap <= GAP_TOLERANCE and self.max_violation <= VIOLATION_TOLERANCE


def pair_problem(D: np.ndarray, G: np.ndarray, margin: float = 0.0) -> PairProblem:
    """The pairs of two full symmetric matrices, with similarity levels."""
    D = np.asarray(D, dtype=np.float64)
    G = np.asarray(G, dtype=np.float64)
    if D.ndim != 2 or D.shape[0] != D.shape[1] or G.shape != D.shape:
        raise ValueError(f"D and G must be square and of one shape, got {D.shape} and {G.shape}")
    if not (np.all(np.isfinite(D)) and np.all(np.isfinite(G))):
        raise ValueError("D and G must be finite")
    if not (np.allclose(D, D.T) and np.allclose(G, G.T)):
        raise ValueError("D and G must be symmetric")
    if margin < 0 or not np.isfinite(margin):
        raise ValueError(f"margin must be finite and >= 0, got {margin}")
    upper = np.triu_indices(D.shape[0], 1)
    d = D[upper]
    g = np.round(G[upper], LEVEL_DECIMALS)
    values, inverse = np.unique(-g, return_inverse=True)
    return PairProblem(d=d, level=inverse.astype(np.int64), n_levels=len(values), margin=margin)


def exact_pairs(problem: PairProblem) -> np.ndarray:
    """The optimum, by pool-adjacent-violators (see the module docstring)."""
    shift = problem.margin * problem.level
    order = np.lexsort((problem.d, problem.level))
    fitted = isotonic_regression((problem.d - shift)[order]).x
    f = np.empty_like(problem.d)
    f[order] = np.maximum(fitted, 0.0)
    return f + shift


def osqp_pairs(
    problem: PairProblem, *, eps: float = 1e-5, max_iter: int = 20_000
) -> tuple[np.ndarray, dict[str, float | int | str]]:
    """The optimum by OSQP on the sparse boundary formulation, its boundary values
    polished (``polish_boundaries``) and f recovered from them (``recover_pairs``);
    also the solver's report."""
    raw, boundaries, report = solve_boundary_qp(problem, eps=eps, max_iter=max_iter)
    polished = polish_boundaries(problem, boundaries)
    f = recover_pairs(problem, polished)
    report["raw_max_change"] = float(np.abs(f - raw).max(initial=0.0))
    report["polish_max_change"] = float(np.abs(polished - boundaries).max(initial=0.0))
    return f, report


def solve_boundary_qp(
    problem: PairProblem, *, eps: float = 1e-5, max_iter: int = 20_000, rho: float = RHO
) -> tuple[np.ndarray, np.ndarray, dict[str, float | int | str]]:
    """OSQP on the sparse formulation: (raw f, boundary values t, report).

    Settings, tuned on bench/fusion.py: tolerances 1e-5 (OSQP's default is 1e-3),
    distances scaled to at most 1 and a fixed step size ``rho`` (adaptive updates
    refactorise the KKT matrix, which at 1e5 pairs costs as much as a hundred
    iterations), over-relaxation 1.8. OSQP's own polishing is off: with the
    boundary variables the active set is degenerate (many pairs tight at one t, a
    boundary's t free when no pair is tight) and its polish step failed on nearly
    every instance tried; ``recover_pairs`` does that job exactly.
    """
    n, levels, level = problem.d.size, problem.n_levels, problem.level
    if n == 0:
        return np.zeros(0), np.zeros(max(levels - 1, 0)), {"status": "empty", "iterations": 0}
    n_aux = levels - 1
    # distances scaled to at most 1, so one step size suits every problem
    scale = max(float(problem.d.max()), problem.margin, 1e-300)
    d, margin = problem.d / scale, problem.margin / scale
    pairs = np.arange(n)
    below = pairs[level < levels - 1]  # f_k - t_level <= 0
    above = pairs[level > 0]  # f_k - t_(level-1) >= margin
    first = pairs[level == 0]  # f_k >= 0 (the rest follow from the order)
    rows = len(below) + len(above) + len(first)
    row_index = np.concatenate(
        [
            np.repeat(np.arange(len(below)), 2),
            len(below) + np.repeat(np.arange(len(above)), 2),
            len(below) + len(above) + np.arange(len(first)),
        ]
    )
    col_index = np.concatenate(
        [
            np.column_stack([below, n + level[below]]).ravel(),
            np.column_stack([above, n + level[above] - 1]).ravel(),
            first,
        ]
    )
    values = np.concatenate(
        [
            np.tile([1.0, -1.0], len(below)),
            np.tile([1.0, -1.0], len(above)),
            np.ones(len(first)),
        ]
    )
    A = sp.csc_matrix((values, (row_index, col_index)), shape=(rows, n + n_aux))
    lower = np.concatenate(
        [np.full(len(below), -np.inf), np.full(len(above), margin), np.zeros(len(first))]
    )
    upper = np.concatenate(
        [np.zeros(len(below)), np.full(len(above), np.inf), np.full(len(first), np.inf)]
    )
    P = sp.diags(np.concatenate([np.ones(n), np.zeros(n_aux)]), format="csc")
    q = np.concatenate([-d, np.zeros(n_aux)])
    solver = osqp.OSQP()
    solver.setup(
        P,
        q,
        A,
        lower,
        upper,
        eps_abs=eps,
        eps_rel=eps,
        alpha=1.8,
        rho=rho,
        adaptive_rho=False,
        max_iter=max_iter,
        polishing=False,
        verbose=False,
    )
    result = solver.solve(raise_error=False)
    if result.x is None or not np.all(np.isfinite(result.x)):
        raise RuntimeError(f"OSQP failed: {result.info.status}")
    report: dict[str, float | int | str] = {
        "status": str(result.info.status),
        "iterations": int(result.info.iter),
    }
    x = np.asarray(result.x, dtype=np.float64) * scale
    return x[:n], x[n:], report


def recover_pairs(problem: PairProblem, boundaries: np.ndarray) -> np.ndarray:
    """The exact minimiser over f for given boundary values t: f_k = d_k clipped to
    its level's slot [t_(l-1) + margin, t_l] (level 0 from 0, the last one unbounded).

    Applied to OSQP's t, it turns an ADMM answer accurate to eps into one that meets
    the order constraints exactly and whose objective is off by O(eps^2): the
    objective is smooth in t, while f read straight off the solver carries O(eps)
    violations.
    """
    t = _chained(problem, boundaries)
    lows = np.concatenate([[0.0], t + problem.margin])
    highs = np.concatenate([t, [np.inf]])
    return np.clip(problem.d, lows[problem.level], highs[problem.level])


def _chained(problem: PairProblem, boundaries: np.ndarray) -> np.ndarray:
    """Boundaries with nonempty slots: 0 <= t_0 and t_l + margin <= t_(l+1)."""
    t = np.asarray(boundaries, dtype=np.float64).copy()
    for index in range(len(t)):
        floor = 0.0 if index == 0 else t[index - 1] + problem.margin
        t[index] = max(t[index], floor)
    return t


def polish_boundaries(problem: PairProblem, boundaries: np.ndarray, rounds: int = 3) -> np.ndarray:
    """OSQP's polish, done in closed form for this problem.

    From the solver's boundary values, guess the active set: which pairs are clipped
    to which boundary (level l's pairs above t_l, level l+1's below t_l + margin),
    and which consecutive boundaries are tied (a level squeezed to t_l + margin =
    t_(l+1), or t_0 held at 0). The equality-constrained QP that guess defines has a
    closed-form answer: each group of tied boundaries moves as one, to the mean of
    its active pairs' targets. Keep the step only if it lowers the objective.
    OSQP's built-in polish cannot do this here: a boundary with no active pair has a
    free t_l, which leaves its reduced KKT system singular, so it fails.
    """
    t = _chained(problem, boundaries)
    if problem.n_levels < 2:
        return t
    scale = max(float(problem.d.max(initial=0.0)), problem.margin, 1e-300)
    best_t, best = t, problem.objective(recover_pairs(problem, t))
    # which boundaries are tied is read off the solver's answer, accurate to about its
    # tolerance: try a few thresholds, keep the best
    for tolerance in (1e-4 * scale, 1e-6 * scale, 1e-8 * scale):
        current, objective = t, problem.objective(recover_pairs(problem, t))
        for _ in range(rounds):
            step = _active_set_step(problem, current, tolerance)
            step_objective = problem.objective(recover_pairs(problem, step))
            if not step_objective < objective:
                break
            current, objective = step, step_objective
        if objective < best:
            best_t, best = current, objective
    return best_t


def _active_set_step(problem: PairProblem, t: np.ndarray, tolerance: float) -> np.ndarray:
    d, level, levels, margin = problem.d, problem.level, problem.n_levels, problem.margin
    # groups of tied boundaries: group[b] is the first boundary of b's group
    tied = np.diff(t) - margin <= tolerance
    group = np.zeros(levels - 1, dtype=np.int64)
    for b in range(1, levels - 1):
        group[b] = group[b - 1] if tied[b - 1] else b
    # pairs clipped to a boundary: f_k = t_b + offset_k
    lows = np.concatenate([[0.0], t + margin])[level]
    highs = np.concatenate([t, [np.inf]])[level]
    down = (level < levels - 1) & (d >= highs)
    up = (level > 0) & (d <= lows) & ~down
    boundary = np.concatenate([level[down], level[up] - 1])
    target = np.concatenate([d[down], d[up] - margin])
    # within a group, t_b = t_first + margin * (b - first): one unknown per group
    first = group[boundary]
    target = target - margin * (boundary - first)
    sums = np.zeros(levels - 1)
    counts = np.zeros(levels - 1)
    np.add.at(sums, first, target)
    np.add.at(counts, first, 1.0)
    base = np.where(counts > 0, sums / np.maximum(counts, 1.0), t)
    # t_0 >= 0 (f >= 0): held at 0 when the solver put it there
    base[0] = 0.0 if t[0] <= tolerance else max(base[0], 0.0)
    return _chained(problem, base[group] + margin * (np.arange(levels - 1) - group))


def check_pairs(
    problem: PairProblem, f: np.ndarray, exact: np.ndarray | None = None
) -> FusionCheck:
    """Relative objective gap to the exact optimum and the largest order/sign violation."""
    if exact is None:
        exact = exact_pairs(problem)
    objective, best = problem.objective(f), problem.objective(exact)
    scale = max(best, 1e-12 * float(np.sum(problem.d**2)), 1e-300)
    violation = max(0.0, float(-f.min(initial=0.0)))
    if problem.n_levels > 1:
        highest = np.full(problem.n_levels, -np.inf)
        lowest = np.full(problem.n_levels, np.inf)
        np.maximum.at(highest, problem.level, f)
        np.minimum.at(lowest, problem.level, f)
        # every pair of level l+1 must be >= every pair of level l, plus the margin
        gaps = highest[:-1] + problem.margin - lowest[1:]
        violation = max(violation, float(gaps.max()))
    return FusionCheck(
        objective=objective,
        exact_objective=best,
        relative_gap=abs(objective - best) / scale,
        max_violation=violation,
    )


def _full(problem_size: int, f: np.ndarray) -> np.ndarray:
    F = np.zeros((problem_size, problem_size))
    upper = np.triu_indices(problem_size, 1)
    F[upper] = f
    return F + F.T


def fuse(
    D: np.ndarray, G: np.ndarray, margin: float = 0.0, solver: Solver = "osqp"
) -> tuple[np.ndarray, dict[str, float | int | str]]:
    """Fused distances (full symmetric) and diagnostics of the solve and its check."""
    problem = pair_problem(D, G, margin)
    started = time.perf_counter()
    exact = exact_pairs(problem)
    exact_seconds = time.perf_counter() - started
    info: dict[str, float | int | str] = {
        "fusion_solver": solver,
        "fusion_pairs": int(problem.d.size),
        "fusion_levels": problem.n_levels,
        "fusion_exact_seconds": exact_seconds,
    }
    f = exact
    if solver == "osqp":
        started = time.perf_counter()
        candidate, report = osqp_pairs(problem)
        info["fusion_osqp_seconds"] = time.perf_counter() - started
        info.update({f"fusion_osqp_{key}": value for key, value in report.items()})
        check = check_pairs(problem, candidate, exact)
        info["fusion_relative_gap"] = check.relative_gap
        info["fusion_max_violation"] = check.max_violation
        if check.ok:
            f = candidate
        else:
            info["fusion_fallback"] = "exact"
    elif solver != "exact":
        raise ValueError(f"unknown fusion solver {solver!r} (osqp or exact)")
    info["fusion_objective"] = problem.objective(f)
    return _full(D.shape[0], f), info


def fuse_distances(
    D: np.ndarray, G: np.ndarray, margin: float = 0.0, solver: Solver = "osqp"
) -> np.ndarray:
    """Fused distances F (full symmetric, zero diagonal) of spec distances D and
    structure similarities G; see the module docstring."""
    return fuse(np.asarray(D, dtype=np.float64), G, margin, solver)[0]


def fusion_check(D: np.ndarray, G: np.ndarray, F: np.ndarray, margin: float = 0.0) -> FusionCheck:
    """How far a fused matrix F is from the exact optimum, and how much it breaks the order."""
    problem = pair_problem(D, G, margin)
    upper = np.triu_indices(np.asarray(D).shape[0], 1)
    return check_pairs(problem, np.asarray(F, dtype=np.float64)[upper])
