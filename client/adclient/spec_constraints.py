"""Linear constraints on a design's specs (budgets): ``sum(terms[k] * spec k) op bound``.

``spec_constraints: [{terms: {a.length: 1.0, b.length: 1.0}, op: "<=", bound: 1.2}]``
says the two links are at most 1.2 m together. Terms name specs as params do
(``"<instance>.<spec>"``, ``"<instance>.joint.<spec>"``) in physical units; the same
``op``/``bound`` as outcome constraints. Every proposal satisfies them (the search
box is cut by them, ``adclient.polytope``) and an enqueued design that breaks one is
refused, naming it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Literal

from pydantic import Field, field_validator

from adclient.strict import StrictInput

TOLERANCE = 1e-9
"""How far past its bound (relative to the bound's and the terms' scale) a design may be
and still satisfy a constraint: the rounding of a sum of floats."""


class SpecConstraint(StrictInput):
    terms: dict[str, float] = Field(min_length=1, max_length=64)
    op: Literal["<=", ">="]
    bound: float = Field(allow_inf_nan=False)

    @field_validator("terms")
    @classmethod
    def _finite(cls, terms: dict[str, float]) -> dict[str, float]:
        for key, coefficient in terms.items():
            if not math.isfinite(coefficient) or coefficient == 0.0:
                raise ValueError(f"terms.{key}: a coefficient is a finite non-zero number")
        return terms

    def describe(self) -> str:
        """The constraint as a person writes it: ``a.length + 2 b.length <= 1.2``."""
        parts = []
        for number, (key, coefficient) in enumerate(self.terms.items()):
            sign = "-" if coefficient < 0 else "+"
            size = abs(coefficient)
            scaled = key if size == 1.0 else f"{size:g} {key}"
            parts.append(
                f"{'-' if sign == '-' else ''}{scaled}" if number == 0 else f"{sign} {scaled}"
            )
        return f"{' '.join(parts)} {self.op} {self.bound:g}"

    def total(self, values: Mapping[str, float]) -> float:
        """The constrained sum for specs ``values`` (physical)."""
        return math.fsum(coefficient * values[key] for key, coefficient in self.terms.items())

    def holds(self, values: Mapping[str, float]) -> bool:
        total = self.total(values)
        scale = max(1.0, abs(self.bound), *(abs(c * values[k]) for k, c in self.terms.items()))
        slack = total - self.bound if self.op == "<=" else self.bound - total
        return slack <= TOLERANCE * scale
