"""The one base of every model a client sends (request bodies, the study file's space,
pruner, objectives and spec constraints): unknown keys refused, and types taken as JSON
gives them, so a quoted number, a truth value where a number goes, or a number where
text goes is an error naming the field (pydantic's lax mode read ``"5"`` as 5 and
``true`` as 1, and stored them).

What JSON cannot tell apart is accepted: an integral number where an integer goes (5.0,
``1e5`` as YAML 1.2 reads it) is that integer, and a NumPy number a Python script passes
is the Python number. A fractional number where an integer goes stays an error.
"""

from __future__ import annotations

import functools
import json
import numbers
import types
from typing import Any, Literal, TypeVar, Union, get_args, get_origin

from pydantic import BaseModel, ConfigDict, model_validator

NumberKind = Literal["int", "float", "number"]
ModelT = TypeVar("ModelT", bound=BaseModel)


class StrictInput(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True)

    @model_validator(mode="before")
    @classmethod
    def _plain_numbers(cls, data: Any) -> Any:
        """Integral numbers for integer fields, NumPy numbers as Python's (the module
        docstring); everything else as given, for the strict fields to judge."""
        if not isinstance(data, dict):
            return data
        changed: dict[str, Any] | None = None
        for key, kind in number_fields(cls).items():
            if key in data:
                value = plain_number(data[key], kind)
                if value is not data[key]:
                    changed = changed if changed is not None else dict(data)
                    changed[key] = value
        return data if changed is None else changed


@functools.cache
def number_fields(model: type[BaseModel]) -> dict[str, NumberKind]:
    """The fields of ``model`` (by the key a body gives) that hold one number: an
    integer, a float, or either; None allowed."""
    found: dict[str, NumberKind] = {}
    for name, field in model.model_fields.items():
        annotation = field.annotation
        union = get_origin(annotation) in (Union, types.UnionType)
        kinds = (
            {arg for arg in get_args(annotation) if arg is not type(None)}
            if union
            else {annotation}
        )
        if kinds == {int}:
            found[field.alias or name] = "int"
        elif kinds == {float}:
            found[field.alias or name] = "float"
        elif kinds == {int, float}:
            found[field.alias or name] = "number"
    return found


def plain_number(value: Any, kind: NumberKind) -> Any:
    """``value`` as the Python number a strict field of ``kind`` takes, where JSON means
    that number (a NumPy scalar, an integral float for an integer); else ``value``."""
    if type(value).__module__ == "numpy" and isinstance(value, numbers.Real):
        value = int(value) if isinstance(value, numbers.Integral) else float(value)
    if kind == "int" and isinstance(value, float) and value.is_integer():
        return int(value)
    return value


def validate_strictly(model: type[ModelT], data: Any) -> ModelT:
    """``data``, a JSON value, as ``model`` with a body's strict types, whatever the
    model's own mode: a new study's proposer, task and learner options are checked so
    (their models are the proposers' and plugins' own), while options a study stored are
    read as their model reads them (an older server let lax values in). Validated as
    JSON, so an enum takes its value and a tuple an array, as a body gives them."""
    if isinstance(data, dict):
        kinds = number_fields(model)
        data = {
            key: plain_number(value, kinds[key]) if key in kinds else value
            for key, value in data.items()
        }
    return model.model_validate_json(json.dumps(data), strict=True)
