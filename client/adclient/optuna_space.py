"""An Optuna search space as a service study's box of params, and values back and forth.

:func:`box_param` says whether the service can hold one Optuna distribution (a float,
an int, each with ``log`` or ``step``, or a categorical) and, if not, why: the box
param's own schema decides (finite bounds within its limits, choices of one kind, at
most 1000 of them, no ``None``). :class:`RelativeSpace` is a set of such params under
names the service accepts (an Optuna name outside the service's name pattern is
renamed, the same way on every run), and turns a service trial into the Optuna
trial's params and an Optuna trial's params into the service's.

Used by :mod:`adclient.optuna`; needs Optuna installed.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from functools import cached_property
from typing import Any

from optuna.distributions import (
    BaseDistribution,
    CategoricalDistribution,
    FloatDistribution,
    IntDistribution,
)
from pydantic import ValidationError

from adclient.boxspace import BoxEncoding
from adclient.calls import validation_message
from adclient.schemas import BoxParam, Trial
from adclient.schemas.common import NAME_PATTERN
from adclient.schemas.space import MAX_CHOICES

MAX_PARAMS = 256
"""The most params one box study holds (``BoxSpace.params``)."""


def box_param(name: str, distribution: BaseDistribution) -> BoxParam | str:
    """The box param (named ``name``) that stands for ``distribution``, or why the
    service cannot hold it."""
    body: dict[str, Any] = {"name": name}
    if isinstance(distribution, FloatDistribution | IntDistribution):
        kind = "float" if isinstance(distribution, FloatDistribution) else "int"
        body.update(type=kind, low=distribution.low, high=distribution.high)
        if distribution.log:
            body["log"] = True
        if distribution.step is not None and not (kind == "int" and distribution.step == 1):
            body["step"] = distribution.step
        if not math.isfinite(distribution.high - distribution.low):
            return f"its range [{distribution.low}, {distribution.high}] is too wide"
    elif isinstance(distribution, CategoricalDistribution):
        if any(choice is None for choice in distribution.choices):
            return "a choice is None"
        if len(distribution.choices) > MAX_CHOICES:
            return f"it has {len(distribution.choices)} choices (the service takes {MAX_CHOICES})"
        body.update(type="categorical", choices=list(distribution.choices))
    else:
        return f"the service has no {type(distribution).__name__}"
    try:
        return BoxParam.model_validate(body)
    except ValidationError as exc:
        return validation_message(exc)


def service_names(names: Iterable[str]) -> dict[str, str]:
    """Optuna's param names -> names the service accepts: each valid one as it is, each
    other one with its odd characters replaced by ``_`` (and a number added where that
    meets a name already taken). The same names give the same answer on every run."""
    names = sorted(set(names))
    mapped = {name: name for name in names if re.fullmatch(NAME_PATTERN, name)}
    taken = set(mapped)
    for name in names:
        if name in mapped:
            continue
        base = re.sub(r"[^A-Za-z0-9_.\-]", "_", name)
        if not base[:1].isalnum():
            base = "p" + base
        base = base[:120]
        candidate, number = base, 1
        while candidate in taken:
            number += 1
            candidate = f"{base}-{number}"
        mapped[name] = candidate
        taken.add(candidate)
    return mapped


def _kind(distribution: BaseDistribution | None) -> str | None:
    for kind in (FloatDistribution, IntDistribution, CategoricalDistribution):
        if isinstance(distribution, kind):
            return kind.__name__
    return None


def _same_choice(choice: Any, value: Any) -> bool:
    """Equal and of one kind: ``True`` is not ``1``, ``1`` is ``1.0``."""
    return isinstance(choice, bool) == isinstance(value, bool) and choice == value


@dataclass(frozen=True)
class RelativeSpace:
    """Optuna's relative search space as a box study's params (names sorted)."""

    distributions: dict[str, BaseDistribution]
    names: dict[str, str]
    """Optuna name -> the service's name of the param."""

    @classmethod
    def of(cls, distributions: Mapping[str, BaseDistribution]) -> RelativeSpace:
        """Of distributions that :func:`box_param` takes (see
        :meth:`expressible`)."""
        ordered = dict(sorted(distributions.items()))
        return cls(ordered, service_names(ordered))

    @staticmethod
    def expressible(
        distributions: Mapping[str, BaseDistribution],
    ) -> tuple[dict[str, BaseDistribution], dict[str, str]]:
        """The distributions the service can hold (up to :data:`MAX_PARAMS`, by name),
        and why each other one is left out."""
        kept: dict[str, BaseDistribution] = {}
        left: dict[str, str] = {}
        names = service_names(distributions)
        for name, distribution in sorted(distributions.items()):
            param = box_param(names[name], distribution)
            if isinstance(param, str):
                left[name] = param
            elif len(kept) >= MAX_PARAMS:
                left[name] = f"a box study holds at most {MAX_PARAMS} params"
            else:
                kept[name] = distribution
        return kept, left

    @cached_property
    def params(self) -> list[BoxParam]:
        params = []
        for name, distribution in self.distributions.items():
            param = box_param(self.names[name], distribution)
            if isinstance(param, str):
                raise ValueError(f"param {name!r}: {param}")
            params.append(param)
        return params

    @cached_property
    def box(self) -> dict[str, Any]:
        """The box space, as JSON (what a study answer's ``space`` dumps to)."""
        return {"type": "box", "params": [p.model_dump(mode="json") for p in self.params]}

    @cached_property
    def renamed(self) -> dict[str, str]:
        """Service name -> Optuna name, of the params renamed."""
        return {new: old for old, new in self.names.items() if new != old}

    def to_optuna(self, trial: Trial) -> dict[str, Any]:
        """A service trial's params as Optuna's: ints as int, floats inside their range,
        each choice the very object of the distribution's ``choices``."""
        params: dict[str, Any] = {}
        for name, distribution in self.distributions.items():
            value = trial.params[self.names[name]]
            if isinstance(distribution, CategoricalDistribution):
                params[name] = next(
                    choice for choice in distribution.choices if _same_choice(choice, value)
                )
            elif isinstance(distribution, IntDistribution):
                params[name] = int(value)
            else:
                assert isinstance(distribution, FloatDistribution)
                params[name] = min(max(float(value), distribution.low), distribution.high)
        return params

    def to_service(
        self, params: Mapping[str, Any], distributions: Mapping[str, BaseDistribution]
    ) -> dict[str, Any] | None:
        """An Optuna trial's params (suggested from ``distributions``) as the service
        study's, or None unless the trial has each param of this space, of the same
        kind, with a value the space holds."""
        body: dict[str, Any] = {}
        for name, distribution in self.distributions.items():
            if name not in params or _kind(distributions.get(name)) != _kind(distribution):
                return None
            body[self.names[name]] = params[name]
        try:
            return BoxEncoding(tuple(self.params)).given(body)
        except ValueError:
            return None
