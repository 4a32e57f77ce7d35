"""A box space's typed params as the vector proposers search, and back.

A trial's ``vector`` (what proposers see and the database keeps) has one number per
param, its *encoding*:

- float: the value; on a log scale its natural log; with a ``step``, the value on
  the grid ``low + k * step``;
- int: the integer (as a float); on a log scale its natural log;
- categorical: the index of the value in ``choices`` (0, 1, ...).

The search box (``bounds``) is, per coordinate, ``[low, high]`` for a plain float (an
old float-only study's vectors and bounds are exactly what they were), ``[ln low, ln
high]`` for a log float, the grid widened by half a step on each side for an int or a
stepped float (on a log scale: ``[ln(low - 1/2), ln(high + 1/2)]``) and ``[-1/2, k -
1/2]`` for a categorical of k choices. Rounding a uniform draw from that box therefore
gives every int, grid value and choice the same chance (the end values included), as
Optuna's samplers do, and a uniform draw of a log coordinate is log-uniform.

``snap`` turns any point of the box into the canonical vector of the params it stands
for; proposers search the box, the service snaps what they propose before storing it,
so stored vectors of ints and choices are exactly integral and equal vectors are equal
params (duplicates and pending points compare in this space).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np

from adclient.errors import quoted
from adclient.schemas import BoxParam, BoxSpace


def _kind(value: Any) -> str:
    return "text" if isinstance(value, str) else "boolean" if isinstance(value, bool) else "number"


@dataclass(frozen=True)
class BoxEncoding:
    """The encoding of one box space (see the module docstring)."""

    params: tuple[BoxParam, ...]

    @classmethod
    def of(cls, space: dict[str, Any]) -> BoxEncoding:
        """From a box or template space as JSON, as stored (old float-only spaces
        included): a template's params are searched as a box's (none: a zero-length
        vector, its one design)."""
        if not space.get("params"):
            return cls(())
        return cls(
            tuple(BoxSpace.model_validate({"type": "box", "params": space["params"]}).params)
        )

    @property
    def names(self) -> list[str]:
        return [param.name for param in self.params]

    @cached_property
    def typed(self) -> bool:
        """Whether any param is more than a plain float (proposers then need this object)."""
        return any(p.type != "float" or p.log or p.step is not None for p in self.params)

    @cached_property
    def categorical(self) -> dict[int, int]:
        """Column -> number of choices, for each categorical param (values 0 .. k-1)."""
        return {
            i: len(p.choices or []) for i, p in enumerate(self.params) if p.type == "categorical"
        }

    @cached_property
    def ordinal(self) -> tuple[int, ...]:
        """Columns of ints and stepped floats: ordered values, apart by one step."""
        return tuple(
            i
            for i, p in enumerate(self.params)
            if p.type == "int" or (p.type == "float" and p.step is not None)
        )

    @cached_property
    def continuous(self) -> np.ndarray:
        """Mask of the columns that take any value in their range."""
        mask = np.ones(len(self.params), dtype=bool)
        mask[list(self.ordinal) + list(self.categorical)] = False
        return mask

    @cached_property
    def n_points(self) -> int | None:
        """How many distinct vectors the space has (None: some param is continuous)."""
        if self.continuous.any():
            return None
        return math.prod(self._grid_size(p) for p in self.params)

    @staticmethod
    def _grid_size(param: BoxParam) -> int:
        if param.type == "categorical":
            return len(param.choices or [])
        assert param.low is not None and param.high is not None
        return round((param.high - param.low) / (param.step or 1)) + 1

    @cached_property
    def bounds(self) -> np.ndarray:
        """(2, d) search box of the encoded vectors."""
        low, high = [], []
        for i, p in enumerate(self.params):
            if p.type == "categorical":
                lo, hi = -0.5, len(p.choices or []) - 0.5
            else:
                assert p.low is not None and p.high is not None
                half = 0.5 * (p.step or 1) if i in self.ordinal else 0.0
                lo, hi = float(p.low) - half, float(p.high) + half
                if p.log:
                    lo, hi = math.log(lo), math.log(hi)
            low.append(lo)
            high.append(hi)
        return np.array([low, high], dtype=np.float64)

    def snap(self, X: np.ndarray) -> np.ndarray:
        """Points of the box (n x d, or one vector) -> the canonical vectors of their params."""
        X = np.array(X, dtype=np.float64)
        flat = X.reshape(-1, len(self.params))
        bounds = self.bounds
        flat[:] = np.clip(flat, bounds[0], bounds[1])
        for i, p in enumerate(self.params):
            column = flat[:, i]
            if p.type == "categorical":
                column[:] = np.clip(np.round(column), 0, len(p.choices or []) - 1)
            elif i in self.ordinal:
                assert p.low is not None and p.high is not None
                if p.log:  # ints only: the nearest integer of the value
                    column[:] = np.log(np.clip(np.round(np.exp(column)), p.low, p.high))
                else:
                    step = float(p.step or 1)
                    k = np.clip(np.round((column - p.low) / step), 0, self._grid_size(p) - 1)
                    column[:] = p.low + k * step
            elif p.log:
                assert p.low is not None and p.high is not None
                column[:] = np.clip(column, math.log(p.low), math.log(p.high))
        return flat.reshape(X.shape)

    def decode(self, vector: np.ndarray | list[float]) -> dict[str, Any]:
        """A vector -> params by name, each in its type (ints as int, choices as given)."""
        snapped = self.snap(np.asarray(vector, dtype=np.float64).reshape(-1))
        return {p.name: self._value(p, float(x)) for p, x in zip(self.params, snapped, strict=True)}

    @staticmethod
    def _value(param: BoxParam, x: float) -> Any:
        if param.type == "categorical":
            return (param.choices or [])[round(x)]
        assert param.low is not None and param.high is not None
        value = math.exp(x) if param.log else x
        if param.type == "int":
            return round(value)
        value = min(max(value, float(param.low)), float(param.high))
        if param.step is not None:
            value = float(f"{value:.15g}")  # 0.1 * 3 is 0.30000000000000004: say 0.3
        return value

    def encode(self, params: dict[str, Any]) -> np.ndarray:
        """Params by name -> their vector; ValueError naming a missing, unknown or
        out-of-range param or an unknown choice."""
        unknown = sorted(set(params) - set(self.names))
        if unknown:
            raise ValueError(f"unknown param {unknown[0]!r}; the space has {', '.join(self.names)}")
        vector = []
        for p in self.params:
            if p.name not in params:
                raise ValueError(f"param {p.name!r} is missing")
            vector.append(self._coordinate(p, params[p.name]))
        return self.snap(np.array(vector, dtype=np.float64))

    def given(self, params: dict[str, Any]) -> dict[str, Any]:
        """Params a user hands over (enqueued or added) as their trial keeps them: each
        value exactly as given, in its param's type (a float as float, an int as int, a
        choice as the space names it), so what is enqueued comes back bit for bit, where
        ``decode(encode(...))`` would give ``exp(ln 0.01)`` for a log param. ValueError
        as :meth:`encode`, and for a stepped float off its grid."""
        self.encode(params)
        kept: dict[str, Any] = {}
        for p in self.params:
            value = params[p.name]
            if p.type == "categorical":
                kept[p.name] = (p.choices or [])[round(self._coordinate(p, value))]
            elif p.type == "int":
                kept[p.name] = int(value)
            else:
                if p.step is not None:
                    assert p.low is not None
                    k = (value - p.low) / p.step
                    if abs(k - round(k)) > 1e-9:
                        raise ValueError(
                            f"param {p.name!r}: {value} is not on its grid {p.low} + k * {p.step}"
                        )
                kept[p.name] = float(value)
        return kept

    @staticmethod
    def _coordinate(param: BoxParam, value: Any) -> float:
        where = f"param {param.name!r}"
        if param.type == "categorical":
            for index, choice in enumerate(param.choices or []):
                if _kind(choice) == _kind(value) and choice == value:
                    return float(index)
            raise ValueError(f"{where}: {value!r} is not one of its choices {param.choices}")
        if isinstance(value, bool) or not isinstance(value, int | float) or not _finite(value):
            raise ValueError(f"{where}: {quoted(value)} is not a finite number")
        assert param.low is not None and param.high is not None
        if not param.low <= value <= param.high:
            raise ValueError(f"{where}: {value} is outside [{param.low}, {param.high}]")
        if param.type == "int" and not float(value).is_integer():
            raise ValueError(f"{where}: {value} is not an integer")
        return math.log(value) if param.log else float(value)

    def neighbours(self, X: np.ndarray, column: int) -> tuple[np.ndarray, np.ndarray]:
        """For canonical vectors X (n x d), the encoded values of an ordinal column one
        grid step below and above each (NaN past the ends)."""
        p = self.params[column]
        assert p.low is not None and p.high is not None
        x = X[:, column]
        if p.log:
            value = np.round(np.exp(x))
            below, above = value - 1, value + 1
            with np.errstate(divide="ignore", invalid="ignore"):
                below = np.where(below >= p.low, np.log(np.maximum(below, 1e-300)), np.nan)
            above = np.where(above <= p.high, np.log(above), np.nan)
            return below, above
        step = float(p.step or 1)
        below, above = x - step, x + step
        return (
            np.where(below >= p.low - 1e-9 * step, below, np.nan),
            np.where(above <= p.high + 1e-9 * step, above, np.nan),
        )


def _finite(value: int | float) -> bool:
    """Whether a JSON number is a finite float: an integer past the float range is not
    (``math.isfinite`` raises OverflowError for it)."""
    try:
        return math.isfinite(value)
    except OverflowError:
        return False
