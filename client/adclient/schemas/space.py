"""A study's search space: a box of params, or a design space."""

from __future__ import annotations

import sys
from typing import Annotated, Any, Literal

from pydantic import (
    Field,
    SerializerFunctionWrapHandler,
    field_validator,
    model_serializer,
    model_validator,
)

from adclient.design import DesignSpace
from adclient.schemas.common import NAME_PATTERN, finite, plain_text
from adclient.specs import SUBNORMAL_LOW
from adclient.strict import StrictInput

MAX_TEMPLATE_CHARS = 1_000_000

Choice = Annotated[str | bool | int | float, Field(description="a choice")]
"""A categorical param's choice: text, a boolean or a number, kept exactly as given."""
_NUMERIC_FIELDS = ("low", "high", "log", "step")
MAX_CHOICES = 1000
MAX_STEPS = 1e15
"""The most grid steps of a stepped param: beyond, grid values are no longer exact."""


class BoxParam(StrictInput):
    """One searched param: a float (``log`` scale and a ``step`` grid optional), an int
    (the same options) or a categorical one of ``choices``. Without ``type`` it is a
    float, which is all a box param was before types."""

    name: str = Field(pattern=NAME_PATTERN)
    type: Literal["float", "int", "categorical"] = "float"
    low: int | float | None = None
    high: int | float | None = None
    log: bool = Field(default=False, description="searched on a log scale (low > 0)")
    step: int | float | None = Field(
        default=None, description="values only on the grid low, low + step, ..., high"
    )
    choices: list[Choice] | None = Field(default=None, description="a categorical param's values")

    @model_validator(mode="after")
    def _check_bounds(self) -> BoxParam:
        where = f"param {self.name!r}"
        for field, value in (("low", self.low), ("high", self.high), ("step", self.step)):
            if isinstance(value, int) and abs(value) > 2**53:
                raise ValueError(f"{where}: {field} must be within +-2**53 (exact as a float)")
        if self.type == "categorical":
            return self._check_choices(where)
        if self.choices is not None:
            raise ValueError(f"{where}: choices belong to a categorical param, not {self.type}")
        if self.low is None or self.high is None:
            missing = " and ".join(f for f in ("low", "high") if getattr(self, f) is None)
            article = "an" if self.type == "int" else "a"
            raise ValueError(f"{where}: {article} {self.type} param needs {missing}")
        finite(self.low, f"{where}: low")
        finite(self.high, f"{where}: high")
        if not self.low < self.high:
            raise ValueError(f"{where}: low ({self.low}) must be < high ({self.high})")
        if self.log and self.low <= 0:
            raise ValueError(f"{where}: a log scale needs low > 0, got {self.low}")
        if self.log and self.low < sys.float_info.min:
            raise ValueError(f"{where}: {SUBNORMAL_LOW}, got {self.low}")
        if self.type == "int":
            for bound in ("low", "high", "step"):
                value = getattr(self, bound)
                if value is not None and not float(value).is_integer():
                    raise ValueError(
                        f"{where}: an int param's {bound} must be an integer, got {value}"
                    )
                if value is not None:
                    setattr(self, bound, int(value))
        if self.step is not None:
            self._check_step(where)
        return self

    def _check_step(self, where: str) -> None:
        assert self.step is not None and self.low is not None and self.high is not None
        finite(self.step, f"{where}: step")
        if self.step <= 0:
            raise ValueError(f"{where}: step must be > 0, got {self.step}")
        if self.log:
            raise ValueError(f"{where}: step and log do not go together (a grid is linear)")
        intervals = (self.high - self.low) / self.step
        if not intervals <= MAX_STEPS:
            raise ValueError(f"{where}: step ({self.step}) makes more than {MAX_STEPS:g} steps")
        if abs(intervals - round(intervals)) > 1e-9 * max(1.0, intervals) or round(intervals) < 1:
            raise ValueError(
                f"{where}: step ({self.step}) does not divide the range "
                f"[{self.low}, {self.high}] into whole steps"
            )

    def _check_choices(self, where: str) -> BoxParam:
        given = [name for name in _NUMERIC_FIELDS if name in self.model_fields_set]
        if given and (given != ["log"] or self.log):
            verb = "does" if len(given) == 1 else "do"
            raise ValueError(f"{where}: {', '.join(given)} {verb} not apply to a categorical param")
        if not self.choices:
            raise ValueError(f"{where}: a categorical param needs a non-empty list of choices")
        if len(self.choices) > MAX_CHOICES:
            raise ValueError(f"{where}: at most {MAX_CHOICES} choices, got {len(self.choices)}")
        kinds = {
            "text" if isinstance(c, str) else "boolean" if isinstance(c, bool) else "number"
            for c in self.choices
        }
        if len(kinds) > 1:
            raise ValueError(
                f"{where}: choices must all be of one type, got {' and '.join(sorted(kinds))}"
            )
        for choice in self.choices:
            if isinstance(choice, float):
                finite(choice, f"{where}: choice")
            if isinstance(choice, int) and not isinstance(choice, bool) and abs(choice) > 2**53:
                raise ValueError(f"{where}: a number choice must be within +-2**53")
        seen: list[Any] = []
        for choice in self.choices:
            if choice in seen:
                raise ValueError(f"{where}: choice {choice!r} appears twice")
            seen.append(choice)
        plain_text(self.choices, f"{where}: choices")
        return self

    @model_serializer(mode="wrap")
    def _without_unset(self, handler: SerializerFunctionWrapHandler) -> dict[str, Any]:
        """Fields that do not apply to the type are left out (no nulls in answers)."""
        data: dict[str, Any] = handler(self)
        if self.type == "categorical":
            data.pop("log", None)
        return {key: value for key, value in data.items() if value is not None}


class BoxSpace(StrictInput):
    """A plain continuous box: each param searched between its bounds."""

    type: Literal["box"]
    params: list[BoxParam] = Field(min_length=1, max_length=256)

    @field_validator("params")
    @classmethod
    def _unique_names(cls, params: list[BoxParam]) -> list[BoxParam]:
        seen: set[str] = set()
        for param in params:
            if param.name in seen:
                raise ValueError(f"duplicate param name {param.name!r}")
            seen.add(param.name)
        return params

    @property
    def searches_nothing(self) -> bool:
        """Whether the space is one design (a template without params; a box always has
        params): a study of it repeats that design's evaluation."""
        return not self.params


class TemplateSpace(BoxSpace):
    """Your own robot: a URDF or xacro text (``adclient.templates``) whose args or
    properties are the params, searched as a box's are. A box space in every way but
    the robot (and that it may have no params: then it is one design): a worker
    expands the template at a trial's params and builds that. The
    server checks the template when a study is created (``adclient.templates``), not
    each time a stored space is read."""

    type: Literal["template"]  # type: ignore[assignment]
    params: list[BoxParam] = Field(
        default_factory=list,
        max_length=256,
        description="the searched args and properties; none: the robot as written, one "
        "design whose evaluation the study repeats",
    )
    template: str = Field(
        min_length=1,
        max_length=MAX_TEMPLATE_CHARS,
        description="the URDF or xacro text (the CLI reads a file path given here)",
    )


Space = Annotated[BoxSpace | DesignSpace | TemplateSpace, Field(discriminator="type")]
