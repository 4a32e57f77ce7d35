"""The pieces a design space is made of: part types (links), the shared joint type,
and instances of parts (with their overrides, ties and joint kinds)."""

from __future__ import annotations

from typing import Any, NotRequired, cast

from pydantic import (
    Field,
    SerializerFunctionWrapHandler,
    model_serializer,
    model_validator,
)
from typing_extensions import TypedDict

from adclient.specs import (
    JOINT_SPECS,
    MASS_SPECS,
    NAME_PATTERN,
    OFFSET_SPECS,
    PART_SPECS,
    Bound,
    OptionalSpecValue,
    Shape,
    SpecValue,
    check_limits,
    check_spec,
    drop_unset,
)
from adclient.strict import StrictInput
from adclient.ties import Mirror
from adclient.urdf_model import JointKind


class PartJSON(TypedDict):
    """A part as written, which the API's description shows (a Bound as written is an
    object, as ``Bound``'s own serialiser says)."""

    shape: Shape
    length: float | dict[str, Any]
    radius: float | dict[str, Any]
    mass: NotRequired[float | dict[str, Any]]
    density: NotRequired[float | dict[str, Any]]
    choose: NotRequired[str]


class PartType(StrictInput):
    """A kind of link. Its mass is ``mass`` (kg), or ``density`` (kg/m^3) times its
    volume when it gives ``density`` instead (a solid cylinder: ``density * pi r^2
    length``; ``link_mass``), so that a longer or thicker link weighs more. A part
    gives one of the two: ``density`` alone leaves ``mass`` out (``None``), both is an
    error (``DesignSpace`` names the part), neither is the default ``mass: 1.0``."""

    shape: Shape = "cylinder"
    length: SpecValue = 0.4
    radius: SpecValue = 0.04
    mass: OptionalSpecValue = 1.0
    density: OptionalSpecValue = None
    choose: str | None = None
    """A catalogue (``DesignSpace.catalogues``) whose components this part is: their
    entries named like part specs set those specs."""

    @model_validator(mode="before")
    @classmethod
    def _density_replaces_mass(cls, data: Any) -> Any:
        if isinstance(data, dict) and data.get("density") is not None and "mass" not in data:
            return {**data, "mass": None}
        return data

    @model_validator(mode="after")
    def _check(self) -> PartType:
        for name in PART_SPECS:
            check_spec(name, getattr(self, name), "part")
        return self

    @model_serializer(mode="wrap")
    def _given_mass_spec(self, handler: SerializerFunctionWrapHandler) -> PartJSON:
        """Only the mass spec the part gives is written: a part with ``mass`` has the
        JSON it had before ``density`` existed, so older servers and workers read it."""
        data = handler(self)
        drop_unset(data, *MASS_SPECS, "choose")
        return cast(PartJSON, data)


class JointType(StrictInput):
    type: JointKind = "revolute"
    axis_theta: SpecValue = Bound(low=0.0, high=3.141592653589793)
    axis_phi: SpecValue = Bound(low=0.0, high=3.141592653589793)
    position: SpecValue = 1.0
    lower: SpecValue = -1.5707963267948966
    upper: SpecValue = 1.5707963267948966
    effort: SpecValue = 20.0
    velocity: SpecValue = 5.0
    offset_roll: SpecValue = 0.0
    offset_pitch: SpecValue = 0.0
    offset_yaw: SpecValue = 0.0
    choose: str | None = None
    """A catalogue (``DesignSpace.catalogues``) whose components every joint is: their
    entries named like joint specs (``effort``, ``velocity``) set those specs."""

    @model_serializer(mode="wrap")
    def _set_fields_only(self, handler: SerializerFunctionWrapHandler) -> dict[str, Any]:
        """``choose`` is written only when set and an offset only when not 0, so older
        servers read the JSON."""
        data: dict[str, Any] = handler(self)
        drop_unset(data, "choose")
        for spec in OFFSET_SPECS:
            if data.get(spec) == 0.0:
                del data[spec]
        return data

    @model_validator(mode="after")
    def _check(self) -> JointType:
        for name in JOINT_SPECS:
            check_spec(name, getattr(self, name), "joint")
        check_limits(self.lower, self.upper, "joint")
        return self


class PartInstance(StrictInput):
    """One link of the robot, of a ``part`` type, with its own overrides; or tied:
    ``same_as`` another instance, whose specs and joint it takes (searched once),
    reflected across x = 0 or y = 0 with ``mirror`` (``adclient.ties``). A tied
    instance may leave ``part`` out (it is its source's) and overrides only where it
    sits on its parent (``joint_overrides: {position: ..}``: a robot's front and back
    legs are alike but not in one place)."""

    name: str = Field(pattern=NAME_PATTERN)
    part: str = ""
    same_as: str | None = Field(default=None, pattern=NAME_PATTERN)
    mirror: Mirror | None = None
    overrides: dict[str, SpecValue] = Field(default_factory=dict)
    joint_overrides: dict[str, SpecValue] = Field(default_factory=dict)
    joint_type: JointKind | None = None
    """The kind of its joint to its parent, when not the shared joint's ``type``."""

    @model_serializer(mode="wrap")
    def _tie_when_set(self, handler: SerializerFunctionWrapHandler) -> dict[str, Any]:
        """``same_as``, ``mirror`` and ``joint_type`` are written only when set: an
        instance's JSON is what it was before them, so older servers and workers read
        it."""
        data: dict[str, Any] = handler(self)
        drop_unset(data, "same_as", "mirror", "joint_type")
        return data

    @model_validator(mode="after")
    def _check(self) -> PartInstance:
        if self.mirror is not None and self.same_as is None:
            raise ValueError(
                f"instance {self.name!r}: mirror: {self.mirror} needs same_as (the instance "
                "it mirrors)"
            )
        own = sorted(set(self.joint_overrides) - {"position"})
        if self.same_as is not None and self.joint_type is not None:
            raise ValueError(
                f"instance {self.name!r}: same_as {self.same_as!r} takes that instance's "
                f"joint, its kind included: leave joint_type out"
            )
        if self.same_as is not None and (self.overrides or own):
            names = [*self.overrides, *own]
            raise ValueError(
                f"instance {self.name!r}: same_as {self.same_as!r} takes every spec and the "
                f"joint of that instance, so it overrides none of them ({', '.join(names)}); "
                "only joint_overrides.position (where it sits on its parent) is its own"
            )
        if self.same_as is None and not self.part:
            raise ValueError(
                f"instance {self.name!r}: part is required (or same_as: <instance> to take "
                "another instance's part and specs)"
            )
        for field, known in (("overrides", PART_SPECS), ("joint_overrides", JOINT_SPECS)):
            for key, value in getattr(self, field).items():
                if key not in known:
                    raise ValueError(
                        f"instance {self.name!r}: {field} has unknown key {key!r} "
                        f"(expected one of {', '.join(known)})"
                    )
                check_spec(key, value, f"instance {self.name!r}: {field}")
        return self
