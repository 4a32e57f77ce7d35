"""What a spec is: fixed (a number) or searched (a :class:`Bound`), the spec names of
a part and of a joint, and the checks and sums every spec goes through (volumes,
masses, ranges). The bottom of the design-space model (``adclient.design``)."""

from __future__ import annotations

import math
import sys
from collections.abc import MutableMapping
from typing import Annotated, Any, Literal

from pydantic import (
    BeforeValidator,
    SerializerFunctionWrapHandler,
    ValidationError,
    model_serializer,
    model_validator,
)

from adclient.strict import StrictInput

NAME_PATTERN = r"^[A-Za-z][A-Za-z0-9_\-]{0,63}$"

SUBNORMAL_LOW = (
    f"a log scale's low must be at least {sys.float_info.min} (the smallest normal float: "
    "below it exp(ln low + x span) keeps too few bits to give its slot back)"
)

PART_SPECS: tuple[str, ...] = ("length", "radius", "mass", "density")
"""The searchable specs of a part, in spec-vector order; a link uses one of ``mass``
and ``density`` (``MASS_SPECS``), the other is no spec of it."""

MASS_SPECS: tuple[str, str] = ("mass", "density")
"""How a link's mass is given: its own ``mass`` (kg), or ``density`` (kg/m^3) times its
volume."""

JOINT_SPECS: tuple[str, ...] = (
    "axis_theta",
    "axis_phi",
    "position",
    "lower",
    "upper",
    "effort",
    "velocity",
    "offset_roll",
    "offset_pitch",
    "offset_yaw",
)
"""The searchable specs of a joint, in spec-vector order."""

OFFSET_SPECS: tuple[str, str, str] = ("offset_roll", "offset_pitch", "offset_yaw")
"""How a joint's frame is turned on its parent (radians, URDF's rpy: roll about x, then
pitch about y, then yaw about z, each about the parent's axes); 0 by default, and a
space that never turns one shows none of them (``DesignSpace.uses_offsets``)."""

# JointKind (adclient.urdf_model): revolute, about its axis within [lower, upper]
# (radians); continuous, about its axis all round (lower and upper unused); prismatic,
# along its axis within [lower, upper] (metres); fixed, holding its child, driven by
# nothing (only ``position`` used).

UNUSED_JOINT_SPECS: dict[str, tuple[str, ...]] = {
    "continuous": ("lower", "upper"),
    "fixed": ("axis_theta", "axis_phi", "lower", "upper", "effort", "velocity"),
}
"""The joint specs a kind of joint has no use for: never searched, and set to a
placeholder (``DesignSpace.joint_spec``)."""

PLACEHOLDERS = {"lower": -math.pi, "upper": math.pi, "axis_theta": 0.0, "axis_phi": 0.0}

Shape = Literal["cylinder", "box", "capsule"]

_POSITIVE_SPECS = frozenset({"length", "radius", "mass", "density", "effort", "velocity"})


def drop_unset(data: MutableMapping[str, Any], *keys: str) -> None:
    """Leave out of a serialised model the optional fields it does not set, so its JSON is
    what it was before they existed and older servers and workers read it."""
    for key in keys:
        if key in data and data[key] is None:
            del data[key]


class Bound(StrictInput):
    """A searched spec: any value in [low, high], on a log scale with ``log``.

    Its slot of the spec vector is the value normalised to [0, 1]: linearly, or with
    ``log`` as ``(ln value - ln low) / (ln high - ln low)`` (``adclient.decode``), so a
    proposer searching [0, 1] searches the log scale, as a box param's ``log`` does.
    """

    low: float
    high: float
    log: bool = False

    @model_validator(mode="after")
    def _check(self) -> Bound:
        for name, value in (("low", self.low), ("high", self.high)):
            if not math.isfinite(value):
                raise ValueError(f"bound {name} must be a finite number, got {value!r}")
        if not self.low < self.high:
            raise ValueError(f"bound low ({self.low}) must be < high ({self.high})")
        if self.log and not self.low > 0:
            raise ValueError(f"log: a log scale needs low > 0, got {self.low}")
        if self.log and self.low < sys.float_info.min:
            raise ValueError(f"log: {SUBNORMAL_LOW}, got {self.low}")
        return self

    @model_serializer(mode="wrap")
    def _log_when_set(self, handler: SerializerFunctionWrapHandler) -> dict[str, Any]:
        """``log`` is written only when true: a linear spec's JSON is what it was before
        log specs, so stored spaces and workers of older versions read it unchanged."""
        data: dict[str, Any] = handler(self)
        if not self.log:
            data.pop("log", None)
        return data


def _spec_value(value: Any) -> Any:
    """One clear message for a bad spec, instead of pydantic's two union branches."""
    if isinstance(value, Bound):
        return value
    if isinstance(value, dict):
        try:
            return Bound.model_validate(value)
        except ValidationError as error:
            messages = "; ".join(
                (f"{'.'.join(map(str, item['loc']))}: " if item["loc"] else "")
                + str(item["msg"]).removeprefix("Value error, ")
                for item in error.errors()
            )
            raise ValueError(f"a searched spec is {{low, high}}: {messages}") from None
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(
            f"a spec is a number (fixed) or {{low: .., high: ..}} (searched), got {value!r}"
        )
    if not math.isfinite(value):
        raise ValueError(f"a fixed spec must be a finite number, got {value!r}")
    return float(value)


SpecValue = Annotated[float | Bound, BeforeValidator(_spec_value)]
"""A spec is fixed (a number) or searched (a Bound)."""


def _optional_spec_value(value: Any) -> Any:
    return None if value is None else _spec_value(value)


OptionalSpecValue = Annotated[float | Bound | None, BeforeValidator(_optional_spec_value)]
"""A spec a part may leave out (``null``): its ``mass`` or its ``density``."""


def link_volume(shape: str, length: float, radius: float) -> float:
    """A link's volume (m^3): a solid cylinder's ``pi radius^2 length``, a box's
    ``(2 radius)^2 length``, a capsule's cylinder and its two half-balls."""
    if shape == "box":
        return 4.0 * radius * radius * length
    if shape == "capsule":
        return math.pi * radius * radius * (length + 4.0 * radius / 3.0)
    return math.pi * radius * radius * length


def link_mass(shape: str, length: float, radius: float, density: float) -> float:
    """The mass (kg) of a link of uniform ``density`` (kg/m^3): density times
    ``link_volume``, a solid cylinder's ``density * pi r^2 length``. What a link whose
    part gives ``density`` weighs in its design, its URDF and the simulator."""
    return density * link_volume(shape, length, radius)


def spec_range(value: float | Bound) -> tuple[float, float]:
    """The smallest and largest value a spec can take."""
    if isinstance(value, Bound):
        return value.low, value.high
    return value, value


def is_free(value: float | Bound) -> bool:
    return isinstance(value, Bound)


def check_spec(name: str, value: float | Bound | None, where: str) -> None:
    if value is None:
        return
    low, high = spec_range(value)
    if name in _POSITIVE_SPECS and not low > 0:
        raise ValueError(f"{where}.{name}: must be > 0, got {show_spec(value)}")
    if name == "position" and not (low >= 0.0 and high <= 1.0):
        raise ValueError(
            f"{where}.position: must lie in [0, 1] (a fraction of the parent's length), "
            f"got {show_spec(value)}"
        )


def show_spec(value: float | Bound) -> str:
    if isinstance(value, Bound):
        log = ", log: true" if value.log else ""
        return f"{{low: {value.low}, high: {value.high}{log}}}"
    return repr(value)


def check_limits(lower: float | Bound, upper: float | Bound, where: str) -> None:
    if spec_range(lower)[1] > spec_range(upper)[0]:
        raise ValueError(
            f"{where}: joint limit lower ({show_spec(lower)}) can exceed upper "
            f"({show_spec(upper)}); "
            "the largest lower must be <= the smallest upper"
        )
