"""Keeping proposals inside a design space's spec constraints (``adclient.polytope``).

At creation, ``check_satisfiable`` refuses constraints no design in the search box
meets (a linear program). At each ask, ``into_polytope`` moves a candidate that breaks
one to the nearest point that does not (a quadratic program solved with OSQP, the
solver the fusion already uses), so every proposer's proposals satisfy them: model-based
ones search inside already (``qei`` scores feasible points only) and random draws
again; this is the guarantee behind them all.
"""

from __future__ import annotations

import numpy as np
import osqp
from scipy import sparse
from scipy.optimize import linprog

from adclient.polytope import SpecPolytope

MARGIN = 1e-7
"""How far inside its bounds (relative to a row's scale) a projected point is aimed,
so the QP solver's tolerance leaves it inside."""


def _feasible(A: np.ndarray, b: np.ndarray, bounds: np.ndarray) -> bool:
    result = linprog(
        np.zeros(A.shape[1]),
        A_ub=A,
        b_ub=b,
        bounds=list(zip(bounds[0], bounds[1], strict=True)),
        method="highs",
    )
    return bool(result.status == 0)


def check_satisfiable(polytope: SpecPolytope, bounds: np.ndarray) -> None:
    """ValueError naming the constraints no design satisfies: one alone, or together."""
    if _feasible(polytope.A, polytope.b, bounds):
        return
    alone = [
        f"spec_constraints[{j}] ({constraint.describe()})"
        for j, constraint in enumerate(polytope.constraints)
        if not _feasible(polytope.A[j : j + 1], polytope.b[j : j + 1], bounds)
    ]
    if alone:
        raise ValueError(
            f"no design in the specs' bounds satisfies {', '.join(alone)}: widen the "
            "bounds or the budget"
        )
    every = "; ".join(c.describe() for c in polytope.constraints)
    raise ValueError(
        f"spec_constraints contradict each other: no design satisfies them all ({every})"
    )


def interior_point(polytope: SpecPolytope, bounds: np.ndarray) -> np.ndarray:
    """A point well inside: the centre of the largest box-scaled ball the polytope holds
    (Chebyshev's LP), clipped to the bounds."""
    A, b = polytope.A, polytope.b
    width = bounds[1] - bounds[0]
    norms = np.linalg.norm(A * width, axis=1)
    d = A.shape[1]
    # maximise r: A v + r |A diag(width)| <= b, low + r width <= v <= high - r width
    A_ub = np.vstack(
        [
            np.column_stack([A, norms]),
            np.column_stack([-np.eye(d), width]),
            np.column_stack([np.eye(d), width]),
        ]
    )
    b_ub = np.concatenate([b, -bounds[0], bounds[1]])
    result = linprog(
        np.concatenate([np.zeros(d), [-1.0]]),
        A_ub=A_ub,
        b_ub=b_ub,
        bounds=[(None, None)] * d + [(0.0, None)],
        method="highs",
    )
    if result.status != 0:
        raise ValueError("spec_constraints leave no design to propose")
    return np.clip(result.x[:d], bounds[0], bounds[1])


def into_polytope(
    points: np.ndarray, polytope: SpecPolytope, bounds: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(points, moved): each point that breaks a constraint replaced by the nearest one
    (in units of each coordinate's range) that satisfies them all within the bounds."""
    points = np.array(points, dtype=np.float64, copy=True)
    moved = ~polytope.holds(points)
    if not moved.any():
        return points, moved
    width = np.where(bounds[1] > bounds[0], bounds[1] - bounds[0], 1.0)
    A, b = polytope.A, polytope.b
    d = A.shape[1]
    # in unit coordinates u = (v - low) / width: min |u - p|^2, A diag(width) u <= b - A low
    A_unit = A * width
    scale = 1.0 + np.abs(b) + np.abs(A).sum(axis=1)
    upper = b - A @ bounds[0] - MARGIN * scale
    constraint_matrix = sparse.csc_matrix(np.vstack([A_unit, np.eye(d)]))
    low = np.concatenate([np.full(len(b), -np.inf), np.zeros(d)])
    high = np.concatenate([upper, np.ones(d)])
    inside = None
    for i in np.flatnonzero(moved):
        target = (points[i] - bounds[0]) / width
        solver = osqp.OSQP()
        solver.setup(
            P=sparse.identity(d, format="csc"),
            q=-target,
            A=constraint_matrix,
            l=low,
            u=high,
            eps_abs=1e-10,
            eps_rel=1e-10,
            max_iter=20000,
            polish=True,
            verbose=False,
        )
        result = solver.solve()
        candidate = None
        if result.x is not None and np.all(np.isfinite(result.x)):
            candidate = np.clip(bounds[0] + np.asarray(result.x) * width, bounds[0], bounds[1])
        if candidate is None or not polytope.holds(candidate)[0]:
            # the solver fell short: walk from an interior point towards the target
            if inside is None:
                inside = interior_point(polytope, bounds)
            candidate = _towards(inside, points[i], polytope)
        points[i] = candidate
    return points, moved


def _towards(inside: np.ndarray, target: np.ndarray, polytope: SpecPolytope) -> np.ndarray:
    """The point nearest ``target`` on the segment from ``inside`` that satisfies the
    constraints (bisection; ``inside`` satisfies them)."""
    lo, hi = 0.0, 1.0
    for _ in range(60):
        middle = (lo + hi) / 2
        if polytope.holds(inside + middle * (target - inside))[0]:
            lo = middle
        else:
            hi = middle
    return np.asarray(inside + lo * (target - inside))
