"""The Pareto front of a handful of points by brute force: what the server's fronts and the
dashboard's charts are checked against."""

from __future__ import annotations


def brute_front(points: dict[int, list[float]], signs: list[float]) -> set[int]:
    """The ids of the points no other point dominates; ``signs``: +1 to maximise an
    objective, -1 to minimise it."""

    def dominates(a: list[float], b: list[float]) -> bool:
        pairs = [(s * x, s * y) for s, x, y in zip(signs, a, b, strict=True)]
        return all(x >= y for x, y in pairs) and any(x > y for x, y in pairs)

    return {
        i
        for i, p in points.items()
        if not any(dominates(q, p) for j, q in points.items() if j != i)
    }
