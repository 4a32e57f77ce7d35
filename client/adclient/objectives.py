"""What a study optimises: one or several objectives, and outcome constraints.

A study has 1 to 4 objectives, each with a direction. It names them either as plain
``directions`` (a tell gives ``values``, one number per direction) or as ``objectives``
read from what a trial is told (``{metric, direction}``: ``value`` or ``score`` is the
told value, any other name a told metric; a managed study's workers tell the task score
as the value and secondary metrics such as ``mass`` beside it). Outcome constraints
(``{metric, op, bound}``) are checked on the told metrics: a trial that breaks one is
complete but infeasible.

Kept apart from :mod:`adclient.schemas` so the server, the SDK and exports share one
definition of a study's outcomes, of what a tell means for them, and of dominance.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from enum import StrEnum
from typing import Annotated, Any, Literal

from pydantic import ConfigDict, Field

from adclient.strict import StrictInput

MAX_OBJECTIVES = 4
MAX_CONSTRAINTS = 16
VALUE_METRICS = frozenset({"value", "score"})
"""Objective metrics that mean the told value itself (a managed study's task score)."""

MetricName = Field(min_length=1, max_length=128, pattern=r"^[^\x00]*$")


class Direction(StrEnum):
    minimize = "minimize"
    maximize = "maximize"


DirectionName = Annotated[Direction, Field(strict=False)]
"""A direction as its JSON string (the strict models take an enum by value)."""


class _Frozen(StrictInput):
    model_config = ConfigDict(frozen=True)


class Objective(_Frozen):
    """An objective read from a tell: ``metric`` ``value``/``score`` is the told value,
    any other name the told metric of that name."""

    metric: str = MetricName
    direction: DirectionName = Direction.maximize


class Constraint(_Frozen):
    """``metric op bound`` must hold for a trial to be feasible (``mass <= 2.5``)."""

    metric: str = MetricName
    op: Literal["<=", ">="]
    bound: float = Field(allow_inf_nan=False)

    def slack(self, value: float) -> float:
        """How far ``value`` is past the bound: <= 0 when the constraint holds (BoTorch's
        convention for outcome constraints)."""
        return value - self.bound if self.op == "<=" else self.bound - value

    def __str__(self) -> str:
        return f"{self.metric} {self.op} {self.bound:g}"


class OutcomeError(ValueError):
    """A tell (or a handed-over trial) whose outcome does not fit its study's objectives
    or constraints; the message names what is wrong."""


@dataclass(frozen=True)
class Outcome:
    """What a complete trial's tell means: the value kept as ``Trial.value`` (None for a
    study of several objectives), its objective values, and whether it is feasible
    (None: the study has no constraints)."""

    value: float | None
    values: list[float] | None
    feasible: bool | None


@dataclass(frozen=True)
class Outcomes:
    """A study's objectives and constraints, as the server checks tells against them."""

    directions: tuple[Direction, ...] = (Direction.maximize,)
    names: tuple[str, ...] = ("value",)
    metrics: tuple[str, ...] | None = None
    """Where each objective is read from in a tell (None: the tell's ``values``, or its
    ``value`` for one objective)."""
    constraints: tuple[Constraint, ...] = ()
    reference_point: tuple[float, ...] | None = None

    @property
    def count(self) -> int:
        return len(self.directions)

    @property
    def multi(self) -> bool:
        return self.count > 1

    @property
    def plain(self) -> bool:
        """One objective read from the told value, no constraints: a tell is stored as
        it comes (the hot path)."""
        return not self.multi and self.metrics is None and not self.constraints

    @property
    def signs(self) -> tuple[float, ...]:
        """+1 for each maximised objective, -1 for each minimised one."""
        return tuple(1.0 if d == Direction.maximize else -1.0 for d in self.directions)

    def outcome(
        self, *, value: float | None, values: Sequence[float] | None, metrics: Mapping[str, float]
    ) -> Outcome:
        """The outcome of a complete tell; OutcomeError naming what does not fit."""
        objectives = self._objective_values(value=value, values=values, metrics=metrics)
        feasible = None
        if self.constraints:
            feasible = all(slack <= 0 for slack in self.slacks(metrics, objectives))
        if self.multi:
            return Outcome(value=None, values=objectives, feasible=feasible)
        return Outcome(value=objectives[0], values=None, feasible=feasible)

    def slacks(self, metrics: Mapping[str, float], values: Sequence[float]) -> list[float]:
        """Each constraint's slack for a trial told ``metrics`` with objective ``values``
        (<= 0: it holds)."""
        return [
            c.slack(v)
            for c, v in zip(self.constraints, self._constrained(metrics, values), strict=True)
        ]

    def _objective_values(
        self, *, value: float | None, values: Sequence[float] | None, metrics: Mapping[str, float]
    ) -> list[float]:
        if values is not None:
            if len(values) != self.count:
                raise OutcomeError(
                    f"values: the study has {self.count} objective{'s' if self.multi else ''} "
                    f"({', '.join(self.names)}), so a tell gives {self.count} "
                    f"number{'s' if self.multi else ''}, not {len(values)}"
                )
            return [float(v) for v in values]
        if self.metrics is None:
            if self.multi:
                raise OutcomeError(
                    f"values: the study has {self.count} objectives ({', '.join(self.names)}): "
                    f"tell them as values, a list of {self.count} numbers"
                )
            if value is None:
                raise OutcomeError("value is required to complete a trial")
            return [value]
        found: list[float] = []
        for metric in self.metrics:
            if metric in VALUE_METRICS and metric not in metrics:
                if value is None:
                    raise OutcomeError(f"value: objective {metric!r} is the told value; give it")
                found.append(value)
            elif metric in metrics:
                found.append(float(metrics[metric]))
            else:
                raise OutcomeError(
                    f"metrics: objective {metric!r} is read from the told metrics, and this "
                    f"tell has no metric {metric!r}"
                )
        return found

    def _constrained(self, metrics: Mapping[str, float], values: Sequence[float]) -> list[float]:
        """The number each constraint is on: a told metric, or an objective by name."""
        by_name = dict(zip(self.names, values, strict=True))
        found: list[float] = []
        for constraint in self.constraints:
            if constraint.metric in metrics:
                found.append(float(metrics[constraint.metric]))
            elif constraint.metric in by_name:
                found.append(by_name[constraint.metric])
            else:
                raise OutcomeError(
                    f"metrics: constraint {constraint} is on metric {constraint.metric!r}, "
                    "and this tell has no such metric"
                )
        return found


def dominates(a: Sequence[float], b: Sequence[float], signs: Sequence[float]) -> bool:
    """Whether ``a`` is at least as good as ``b`` in every objective and better in one."""
    better = False
    for x, y, sign in zip(a, b, signs, strict=True):
        if sign * x < sign * y:
            return False
        if sign * x > sign * y:
            better = True
    return better


def pareto_front(points: Sequence[Sequence[float]], signs: Sequence[float]) -> list[int]:
    """Indices of the points no other point dominates, in their order; equal points are
    all kept. Sorting by the first objective first means a point is only compared with
    the front found so far (fast when the front is small, as it is for 2 to 4 objectives
    in practice)."""
    order = sorted(
        range(len(points)),
        key=lambda i: tuple(-s * v for s, v in zip(signs, points[i], strict=True)),
    )
    front: list[int] = []
    for index in order:
        point = points[index]
        if not any(dominates(points[kept], point, signs) for kept in front):
            front.append(index)
    return sorted(front)


def outcomes_of(
    *,
    direction: Direction = Direction.maximize,
    directions: Sequence[Direction] | None = None,
    objective_names: Sequence[str] | None = None,
    objectives: Sequence[Objective] | None = None,
    constraints: Sequence[Constraint] = (),
    reference_point: Sequence[float] | None = None,
) -> Outcomes:
    """A study's outcomes from the fields of a study file (one of ``direction``,
    ``directions`` and ``objectives``)."""
    reference = tuple(reference_point) if reference_point is not None else None
    if objectives:
        metrics = tuple(o.metric for o in objectives)
        return Outcomes(
            directions=tuple(o.direction for o in objectives),
            names=metrics,
            metrics=metrics,
            constraints=tuple(constraints),
            reference_point=reference,
        )
    if directions:
        names = objective_names or (
            ["value"] if len(directions) == 1 else [f"value_{i}" for i in range(len(directions))]
        )
        return Outcomes(
            directions=tuple(directions),
            names=tuple(names),
            constraints=tuple(constraints),
            reference_point=reference,
        )
    return Outcomes(directions=(direction,), constraints=tuple(constraints))


def stored_outcomes(stored: dict[str, Any] | None, *, direction: str) -> Outcomes:
    """A study row's ``outcomes`` column (None: one objective in ``direction``, as every
    study stored before several objectives)."""
    if stored is None:
        return Outcomes(directions=(Direction(direction),))
    metrics = stored.get("metrics")
    reference = stored.get("reference_point")
    return Outcomes(
        directions=tuple(Direction(d) for d in stored["directions"]),
        names=tuple(stored["names"]),
        metrics=tuple(metrics) if metrics else None,
        constraints=tuple(Constraint.model_validate(c) for c in stored.get("constraints", [])),
        reference_point=tuple(reference) if reference else None,
    )


def outcomes_json(outcomes: Outcomes) -> dict[str, Any] | None:
    """What the ``outcomes`` column stores (None for one plain objective)."""
    if outcomes.plain and outcomes.names == ("value",):
        return None
    return {
        "directions": [d.value for d in outcomes.directions],
        "names": list(outcomes.names),
        "metrics": list(outcomes.metrics) if outcomes.metrics is not None else None,
        "constraints": [c.model_dump() for c in outcomes.constraints],
        "reference_point": list(outcomes.reference_point) if outcomes.reference_point else None,
    }


def as_values(value: object) -> list[float] | None:
    """``value`` as a list of objective values when it is a sequence or an array (a tell
    of several objectives), None when it is one number or None."""
    if value is None or isinstance(value, str) or not hasattr(value, "__iter__"):
        return None
    if getattr(value, "ndim", None) == 0:  # a NumPy 0-d array: one number
        return None
    return [float(v) for v in value]
