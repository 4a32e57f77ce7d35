"""A design space's spec constraints as a polytope over its search vectors, and the
check of a design against them (pure numpy: the SDK, the service and workers use it).

Identity, mixed and one-hot representations decode the spec vector by identity, and a
linear spec is an affine function of its [0, 1] slot, so each constraint
(``adclient.spec_constraints``) is one row of ``A v <= b`` over the search vector
``v``: a free spec's slot (or, for a tied instance, its source's slot, a mirrored axis
angle being affine too), a fixed spec a constant. ``DesignSpace`` refuses terms this
cannot express (log-scaled specs, specs some structure lacks, the fused encoding).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from adclient.decode import design_params, spec_layout
from adclient.design import DesignSpace
from adclient.designs import Design, Representation
from adclient.spec_constraints import TOLERANCE, SpecConstraint
from adclient.specs import OFFSET_SPECS
from adclient.ties import mirrored_angle


@dataclass(frozen=True)
class SpecPolytope:
    """``A v <= b`` over search vectors: row j is ``constraints[j]`` (a ``>=`` one negated)."""

    A: np.ndarray
    b: np.ndarray
    constraints: tuple[SpecConstraint, ...]

    def slack(self, vectors: np.ndarray) -> np.ndarray:
        """(n, c) how far each vector is past each bound: <= 0 where it holds."""
        V = np.atleast_2d(np.asarray(vectors, dtype=np.float64))
        return V @ self.A.T - self.b

    def holds(self, vectors: np.ndarray) -> np.ndarray:
        """(n,) whether each vector satisfies every constraint, to rounding."""
        scale = 1.0 + np.abs(self.b) + np.abs(self.A).sum(axis=1)
        return np.all(self.slack(vectors) <= TOLERANCE * scale, axis=1)


def spec_polytope(space: DesignSpace, representation: Representation) -> SpecPolytope | None:
    """The space's spec constraints over ``representation``'s search vectors; None
    when it has none."""
    if not space.spec_constraints:
        return None
    if representation.kind == "fused":
        raise ValueError("spec_constraints need the identity, mixed or onehot representation")
    layout = spec_layout(space)
    offset = {"identity": 0, "mixed": 1, "onehot": len(layout.structures)}[representation.kind]
    dim = len(representation.bounds[0])
    column = {name: k for k, name in enumerate(layout.names)}
    rows, rhs = [], []
    for constraint in space.spec_constraints:
        row = np.zeros(dim)
        constant = 0.0
        for key, coefficient in constraint.terms.items():
            instance, _, rest = key.partition(".")
            if key in column:
                slot, shift, scale = column[key], 0.0, 1.0
            elif key in layout.fixed:
                constant += coefficient * layout.fixed[key]
                continue
            else:  # a tied instance's spec: its source's slot, a mirrored angle affine in it
                tie = layout.ties[instance]
                slot = column[f"{tie.source}.{rest}"]
                spec = rest.removeprefix("joint.")
                shift = mirrored_angle(spec, 0.0, tie)
                scale = mirrored_angle(spec, 1.0, tie) - shift
            low, high = float(layout.low[slot]), float(layout.high[slot])
            row[offset + slot] += coefficient * scale * (high - low)
            constant += coefficient * (shift + scale * low)
        sign = 1.0 if constraint.op == "<=" else -1.0
        rows.append(sign * row)
        rhs.append(sign * (constraint.bound - constant))
    return SpecPolytope(
        A=np.array(rows), b=np.array(rhs), constraints=tuple(space.spec_constraints)
    )


def broken_spec_constraints(space: DesignSpace, design: Design) -> list[str]:
    """The spec constraints a design breaks, each as ``spec_constraints[j] (a.length +
    b.length <= 1.2): the design has 1.31``. Offsets count as 0 in a space that
    turns no joint (its params show none)."""
    unturned = {
        f"{joint.child}.joint.{spec}": 0.0 for joint in design.joints for spec in OFFSET_SPECS
    }
    params = {**unturned, **design_params(design)}
    broken = []
    for number, constraint in enumerate(space.spec_constraints):
        if not constraint.holds(params):
            broken.append(
                f"spec_constraints[{number}] ({constraint.describe()}): the design has "
                f"{constraint.total(params):.6g}"
            )
    return broken
