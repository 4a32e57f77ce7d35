"""The design-space model: parts, joints, instances and candidate tree structures.

A *design space* says which parts a robot is made of, how they may be connected
(candidate tree structures) and which specifications are searched (given as a
``{low, high}`` bound, ``{low, high, log: true}`` on a log scale) or fixed (given as a
number). A *design* is one point of it:
a tree plus concrete specs, ready to be written as URDF.

Geometry conventions (shared by decoding, the URDF writer and the worker tasks):
- Every link frame sits at the joint to its parent. A cylinder link extends along
  the frame's +z axis from 0 to ``length``. A box link is ``2 radius`` by
  ``2 radius`` in x and y and ``length`` along z, over the same span. A capsule
  link is the cylinder with a ball of ``radius`` on each end.
- A child's joint sits on its parent's axis at ``position * parent.length``
  (``position`` = 1.0: at the parent's far end); at joint angle 0 the child's frame
  is its parent's turned by the joint's offset (``offset_roll``, ``offset_pitch``,
  ``offset_yaw``: URDF's rpy, 0 by default), so a chain of unturned joints at rest is
  straight along +z.
- A joint is revolute, continuous, prismatic or fixed (``JointKind``).
- A joint's axis, in the child's frame, is
  ``(sin(theta) cos(phi), sin(theta) sin(phi), cos(theta))``: theta = 0 runs along
  the links, theta = pi/2 is perpendicular to them.
- A link's mass is its ``mass`` spec, or, when its part gives ``density`` (kg/m^3)
  instead, ``density`` times its shape's volume: a solid cylinder's
  ``pi radius^2 length``, a box's ``(2 radius)^2 length`` (``link_mass``). Exactly one
  of the two applies to each link; an instance's override of either replaces its
  part's.
- The spec vector orders the instances' part specs, then the instances' joint specs:
  the joint of an instance is the one to its parent, so every structure has the same
  spec slots; the root's joint slots are padded.

Spec keys: ``"<instance>.<part spec>"`` (``"a.length"``) and
``"<instance>.joint.<joint spec>"`` (``"b.joint.axis_theta"``).
"""

from __future__ import annotations

import heapq
import itertools
import math
import re
import sys
from collections.abc import Iterable, Iterator, Mapping, MutableMapping
from typing import Annotated, Any, Literal, NotRequired, cast

from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    PrivateAttr,
    SerializerFunctionWrapHandler,
    ValidationError,
    model_serializer,
    model_validator,
)
from typing_extensions import TypedDict

from adclient.catalogues import check_catalogue, choice_slots
from adclient.spec_constraints import SpecConstraint
from adclient.ties import Mirror, Tie, mirrored_angle, resolve_ties
from adclient.urdf_model import JointKind

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

_PLACEHOLDERS = {"lower": -math.pi, "upper": math.pi, "axis_theta": 0.0, "axis_phi": 0.0}

Shape = Literal["cylinder", "box", "capsule"]

_POSITIVE_SPECS = frozenset({"length", "radius", "mass", "density", "effort", "velocity"})


def _drop_unset(data: MutableMapping[str, Any], *keys: str) -> None:
    """Leave out of a serialised model the optional fields it does not set, so its JSON is
    what it was before they existed and older servers and workers read it."""
    for key in keys:
        if key in data and data[key] is None:
            del data[key]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class Bound(_Strict):
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


def _check_spec(name: str, value: float | Bound | None, where: str) -> None:
    if value is None:
        return
    low, high = spec_range(value)
    if name in _POSITIVE_SPECS and not low > 0:
        raise ValueError(f"{where}.{name}: must be > 0, got {_show(value)}")
    if name == "position" and not (low >= 0.0 and high <= 1.0):
        raise ValueError(
            f"{where}.position: must lie in [0, 1] (a fraction of the parent's length), "
            f"got {_show(value)}"
        )


def _show(value: float | Bound) -> str:
    if isinstance(value, Bound):
        log = ", log: true" if value.log else ""
        return f"{{low: {value.low}, high: {value.high}{log}}}"
    return repr(value)


def _check_limits(lower: float | Bound, upper: float | Bound, where: str) -> None:
    if spec_range(lower)[1] > spec_range(upper)[0]:
        raise ValueError(
            f"{where}: joint limit lower ({_show(lower)}) can exceed upper ({_show(upper)}); "
            "the largest lower must be <= the smallest upper"
        )


class PartJSON(TypedDict):
    """A part as written, which the API's description shows (a Bound as written is an
    object, as ``Bound``'s own serialiser says)."""

    shape: Shape
    length: float | dict[str, Any]
    radius: float | dict[str, Any]
    mass: NotRequired[float | dict[str, Any]]
    density: NotRequired[float | dict[str, Any]]


class PartType(_Strict):
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
            _check_spec(name, getattr(self, name), "part")
        return self

    @model_serializer(mode="wrap")
    def _given_mass_spec(self, handler: SerializerFunctionWrapHandler) -> PartJSON:
        """Only the mass spec the part gives is written: a part with ``mass`` has the
        JSON it had before ``density`` existed, so older servers and workers read it."""
        data = handler(self)
        _drop_unset(data, *MASS_SPECS, "choose")
        return cast(PartJSON, data)


class JointType(_Strict):
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
        _drop_unset(data, "choose")
        for spec in OFFSET_SPECS:
            if data.get(spec) == 0.0:
                del data[spec]
        return data

    @model_validator(mode="after")
    def _check(self) -> JointType:
        for name in JOINT_SPECS:
            _check_spec(name, getattr(self, name), "joint")
        _check_limits(self.lower, self.upper, "joint")
        return self


class PartInstance(_Strict):
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
        _drop_unset(data, "same_as", "mirror", "joint_type")
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
                _check_spec(key, value, f"instance {self.name!r}: {field}")
        return self


Edge = tuple[str, str]
"""(parent instance, child instance): one joint (revolute unless its kind says)."""


class DesignSpace(_Strict):
    """Parts, instances and candidate trees; see the module docstring for conventions.

    ``structures: "all"`` means every labelled tree over the instances (Cayley:
    n^(n-2) of them for n instances, enumerated through Pruefer sequences), each
    rooted at the first instance with its edges pointing away from the root. The
    first instance is the base: which instance is the root changes the robot's
    geometry (children sit at their parent's far end), so the rooted variants of one
    tree are different robots; list them explicitly to search over them.

    Fusion settings (used only with several structures; see
    ``adservice.representation``): ``fusion_solver`` and ``fusion_margin`` (the gap
    forced between consecutive similarity levels), ``reference_per_structure`` Sobol
    references per structure (capped near 512 in all, at least 2 each) drawn with
    ``reference_seed``, and the embedding's ``embedding_mass`` and
    ``embedding_max_dim``.

    ``encoding`` says how a space with several structures is searched:
    - ``mixed`` (the default, DESIGN.md section 2a): a structure index followed by the
      normalised spec vector, decoded by identity; the fused geometry places the
      structures, and the proposer relates them through a structure kernel;
    - ``fused``: the preprint's encoding (DESIGN.md section 2), the MDS embedding of the
      fused distances decoded by nearest reference and an affine map; kept so the
      benchmarks can compare it (bench/paper.py);
    - ``onehot``: the plain encoding a user would build without fusion: one [0, 1]
      coordinate per structure (the largest names the structure) followed by the
      normalised spec vector.
    Single-structure spaces search the spec vector either way.
    """

    type: Literal["design"]
    parts: dict[str, PartType]
    joint: JointType = Field(default_factory=JointType)
    instances: list[PartInstance] = Field(min_length=1, max_length=32)
    structures: list[list[Edge]] | Literal["all"] = Field(
        description="Candidate trees as edge lists, or 'all' trees over the instances"
    )
    max_structures: int = Field(default=64, ge=1, le=1000)
    encoding: Literal["mixed", "fused", "onehot"] = Field(
        default="mixed",
        description="Search vector of a multi-structure space: structure index + spec "
        "vector (mixed), the preprint's fused MDS embedding (fused), or one-hot "
        "structure + spec vector (onehot)",
    )
    catalogues: dict[str, dict[str, dict[str, float]]] = Field(
        default_factory=dict,
        description="Components a part or the joint may choose from: name -> component -> entries",
    )
    spec_constraints: list[SpecConstraint] = Field(
        default_factory=list,
        max_length=64,
        description="Linear budgets on specs every design satisfies",
    )
    fusion_solver: Literal["osqp", "exact"] = "osqp"
    fusion_margin: float = Field(default=0.0, ge=0.0, allow_inf_nan=False)
    reference_per_structure: int = Field(default=16, ge=2, le=256)
    reference_seed: int = Field(default=0, ge=0, le=2**31 - 1)
    embedding_mass: float = Field(
        default=0.99,
        gt=0.0,
        le=1.0,
        description="Fraction of the positive eigenvalue mass the MDS embedding keeps",
    )
    embedding_max_dim: int | None = Field(
        default=None,
        ge=1,
        le=256,
        description=(
            "Cap on the embedding's dimension; default: free specs + min(structures - 1, 8)"
        ),
    )

    _trees: list[list[Edge]] | None = PrivateAttr(default=None)
    _ties: dict[str, Tie] = PrivateAttr(default_factory=dict)
    _turned: bool | None = PrivateAttr(default=None)

    @model_validator(mode="after")
    def _check(self) -> DesignSpace:
        if not self.parts:
            raise ValueError("parts: at least one part type is needed")
        self._tie_instances()
        self._check_catalogues()
        for part_name, part in self.parts.items():
            if not _valid_name(part_name):
                raise ValueError(f"parts: part type name {part_name!r} must match {NAME_PATTERN}")
            _check_mass_specs(
                part.mass, part.density, f"parts: part {part_name!r}", "leave one out"
            )
        seen: dict[str, int] = {}
        for index, instance in enumerate(self.instances):
            if instance.name in seen:
                raise ValueError(
                    f"instances[{index}]: duplicate instance name {instance.name!r} "
                    f"(also instances[{seen[instance.name]}])"
                )
            seen[instance.name] = index
            if instance.part not in self.parts:
                raise ValueError(
                    f"instances[{index}] ({instance.name!r}): unknown part {instance.part!r} "
                    f"(known: {', '.join(sorted(self.parts))})"
                )
            if all(name in instance.overrides for name in MASS_SPECS):
                _check_mass_specs(
                    instance.overrides["mass"],
                    instance.overrides["density"],
                    f"instances[{index}] ({instance.name!r}): overrides",
                    "override only one (either replaces its part's)",
                )
            _check_limits(
                self.joint_spec(instance.name, "lower"),
                self.joint_spec(instance.name, "upper"),
                f"instances[{index}] ({instance.name!r})",
            )
            kind = self.joint_kind(instance.name)
            unused = sorted(set(instance.joint_overrides) & set(UNUSED_JOINT_SPECS.get(kind, ())))
            if unused:
                raise ValueError(
                    f"instances[{index}] ({instance.name!r}): its joint is {kind}, which has "
                    f"no use for {', '.join(unused)}: leave them out of joint_overrides"
                )
        if self.structures == "all":
            n = len(self.instances)
            if n < 2:
                raise ValueError("structures: 'all' needs at least two instances")
            count = n ** (n - 2)
            if count > self.max_structures:
                raise ValueError(
                    f"structures: 'all' over {n} instances gives {count} trees, more than "
                    f"max_structures={self.max_structures}; list the structures instead "
                    "or raise max_structures (up to 1000)"
                )
        else:
            self._check_structures(self.structures)
        for number, constraint in enumerate(self.spec_constraints):
            self._check_spec_constraint(constraint, f"spec_constraints[{number}]")
        if not self.spec_slots()[0] and len(self.tree_structures()) == 1:
            raise ValueError(
                "nothing to search: no spec used by the structure is given as "
                "{low, high}, and there is a single structure"
            )
        return self

    def _tie_instances(self) -> None:
        """Resolve ``same_as`` chains; a tied instance's part is its source's."""
        names = [instance.name for instance in self.instances]
        if len(set(names)) != len(names):
            return  # the duplicate is named next
        self._ties = resolve_ties(
            {instance.name: instance.same_as for instance in self.instances},
            {instance.name: instance.mirror for instance in self.instances},
        )
        for index, instance in enumerate(self.instances):
            tie = self._ties.get(instance.name)
            if tie is None:
                continue
            source_part = self.instance(tie.source).part
            if not instance.part:
                instance.part = source_part
            elif instance.part != source_part:
                raise ValueError(
                    f"instances[{index}] ({instance.name!r}): part {instance.part!r} differs "
                    f"from {tie.source!r}'s part {source_part!r}; a tied instance is its "
                    "source's part (leave part out)"
                )

    def _check_spec_constraint(self, constraint: SpecConstraint, where: str) -> None:
        """Each term is a spec every structure has, on a linear scale (a log spec is not
        linear in the searched coordinate); the fused encoding decodes non-linearly."""
        if self.encoding == "fused" and len(self.tree_structures()) > 1:
            raise ValueError(
                f"{where}: spec_constraints need the mixed or onehot encoding (the fused "
                "encoding's decoding is not linear, so a proposal could not be kept inside)"
            )
        names = {instance.name for instance in self.instances}
        for key in constraint.terms:
            instance, _, spec = key.partition(".")
            if instance not in names:
                raise ValueError(
                    f"{where}.terms: {key!r} names unknown instance {instance!r} "
                    f"(instances: {', '.join(sorted(names))})"
                )
            joint = spec.startswith("joint.")
            known = [f"joint.{name}" for name in JOINT_SPECS] if joint else list(PART_SPECS)
            if spec not in known:
                raise ValueError(
                    f"{where}.terms: {key!r} is no spec (an instance's specs: "
                    f"{', '.join(PART_SPECS)}; its joint's: joint.{', joint.'.join(JOINT_SPECS)})"
                )
            value = (
                self.joint_spec(instance, spec.removeprefix("joint."))
                if joint
                else self.part_spec(instance, spec)
            )
            if self.catalogue_sets(instance, spec):
                raise ValueError(
                    f"{where}.terms: {key!r} is set by the component chosen from a catalogue; "
                    "constrain its metric instead (outcome constraints on "
                    "'<catalogue>.<entry>')"
                )
            if value is None:
                raise ValueError(
                    f"{where}.terms: {key!r}: {instance!r}'s mass is given by "
                    f"{self.mass_spec(instance)}, so it has no {spec} spec"
                )
            if isinstance(value, Bound) and value.log:
                raise ValueError(
                    f"{where}.terms: {key!r} is searched on a log scale; spec_constraints are "
                    "linear in the searched coordinates, so constrain specs on a linear scale"
                )
            for index, edges in enumerate(self.tree_structures()):
                present = {child for _, child in edges} if joint else {n for e in edges for n in e}
                if instance not in present:
                    raise ValueError(
                        f"{where}.terms: {key!r} is not in structures[{index}] ({instance!r} "
                        f"{'is no child' if joint else 'is absent'} there); a constraint's "
                        "specs must be in every structure"
                    )

    def _check_catalogues(self) -> None:
        """Valid catalogues; every ``choose`` names one; the specs a component sets are
        valid specs of what chooses it."""
        for name, catalogue in self.catalogues.items():
            check_catalogue(name, catalogue)
        choosers = [(f"parts.{n}", part.choose, "part") for n, part in self.parts.items()]
        choosers.append(("joint", self.joint.choose, "joint"))
        for where, chosen, kind in choosers:
            if chosen is None:
                continue
            if chosen not in self.catalogues:
                known = ", ".join(sorted(self.catalogues)) or "none"
                raise ValueError(
                    f"{where}.choose: unknown catalogue {chosen!r} (catalogues: {known})"
                )
            specs = JOINT_SPECS if kind == "joint" else PART_SPECS
            for component, entries in self.catalogues[chosen].items():
                for key, value in entries.items():
                    if key in specs:
                        _check_spec(key, value, f"catalogues.{chosen}.{component}")
                if kind == "joint" and entries.get("lower", -math.inf) > entries.get(
                    "upper", math.inf
                ):
                    raise ValueError(
                        f"catalogues.{chosen}.{component}: lower ({entries['lower']}) exceeds "
                        f"upper ({entries['upper']})"
                    )
            if kind == "part":
                part = self.parts[where.removeprefix("parts.")]
                given = "mass" if part.mass is not None else "density"
                other = "density" if given == "mass" else "mass"
                if other in next(iter(self.catalogues[chosen].values())):
                    raise ValueError(
                        f"{where}.choose: catalogue {chosen!r} sets {other} but the part's "
                        f"mass is given by {given}"
                    )

    def chosen_catalogue(self, instance_name: str, kind: Literal["part", "joint"]) -> str | None:
        """The catalogue an instance's part (or its joint) is chosen from; None if none."""
        if kind == "joint":  # a fixed joint has no motor to choose
            return None if self.joint_kind(instance_name) == "fixed" else self.joint.choose
        return self.parts[self.instance(instance_name).part].choose

    def catalogue_sets(self, instance_name: str, spec: str) -> bool:
        """Whether a component chosen from a catalogue gives this spec (``length``,
        ``joint.effort``), rather than the part or joint itself."""
        kind: Literal["part", "joint"] = "joint" if spec.startswith("joint.") else "part"
        unused = UNUSED_JOINT_SPECS.get(self.joint_kind(instance_name), ())
        if spec.removeprefix("joint.") in unused:
            return False  # its kind has no use for it: a placeholder, whatever the component
        chosen = self.chosen_catalogue(instance_name, kind)
        if chosen is None:
            return False
        first = next(iter(self.catalogues[chosen].values()))
        return spec.removeprefix("joint.") in first

    def tie(self, instance_name: str) -> Tie | None:
        """Where a tied instance's specs come from; None for an untied one."""
        return self._ties.get(instance_name)

    def ties(self) -> dict[str, Tie]:
        """Every tied instance's Tie, by instance name."""
        return dict(self._ties)

    def _check_structures(self, structures: list[list[Edge]]) -> None:
        if not structures:
            raise ValueError("structures: at least one structure is needed")
        if len(structures) > self.max_structures:
            raise ValueError(
                f"structures: {len(structures)} structures, more than "
                f"max_structures={self.max_structures}"
            )
        names = {instance.name for instance in self.instances}
        used: set[str] = set()
        first_of: dict[frozenset[Edge], int] = {}
        for index, edges in enumerate(structures):
            where = f"structures[{index}]"
            _check_tree(edges, names, where)
            key = frozenset(edges)
            if key in first_of:
                raise ValueError(f"{where}: same tree as structures[{first_of[key]}]")
            first_of[key] = index
            for parent, child in edges:
                used.update((parent, child))
        unused = [instance.name for instance in self.instances if instance.name not in used]
        if unused:
            raise ValueError(
                f"instances: {', '.join(map(repr, unused))} appear in no structure; "
                "remove them or use them in a structure"
            )

    # -- queries ---------------------------------------------------------------

    def instance(self, name: str) -> PartInstance:
        for instance in self.instances:
            if instance.name == name:
                return instance
        raise KeyError(f"unknown instance {name!r}")

    def mass_spec(self, instance_name: str) -> Literal["mass", "density"]:
        """Which spec gives an instance's mass: the one it overrides, else the one its
        part gives (``density``: the mass is density times the link's volume)."""
        tie = self.tie(instance_name)
        if tie is not None:
            return self.mass_spec(tie.source)
        instance = self.instance(instance_name)
        for name in MASS_SPECS:
            if name in instance.overrides:
                return "density" if name == "density" else "mass"
        return "mass" if self.parts[instance.part].mass is not None else "density"

    def part_spec(self, instance_name: str, spec: str) -> float | Bound | None:
        """An instance's part spec: its override, else its part type's value; ``None``
        for the one of ``mass`` and ``density`` that does not give its mass. A tied
        instance's is its source's."""
        tie = self.tie(instance_name)
        if tie is not None:
            return self.part_spec(tie.source, spec)
        instance = self.instance(instance_name)
        if spec in MASS_SPECS and spec != self.mass_spec(instance_name):
            return None
        if spec in instance.overrides:
            return instance.overrides[spec]
        value: float | Bound | None = getattr(self.parts[instance.part], spec)
        return value

    def uses_offsets(self) -> bool:
        """Whether any joint of the space is turned on its parent (an offset not 0, or
        searched): its designs then show every joint's offsets."""
        if self._turned is None:  # decoding asks on every ask, lease and job
            self._turned = any(
                self._joint_spec(instance.name, spec) != 0.0
                for instance in self.instances
                for spec in OFFSET_SPECS
            )
        return self._turned

    def joint_kind(self, instance_name: str) -> JointKind:
        """The kind of the joint from an instance to its parent (a tied one's source's)."""
        tie = self.tie(instance_name)
        if tie is not None:
            return self.joint_kind(tie.source)
        return self.instance(instance_name).joint_type or self.joint.type

    def joint_spec(self, instance_name: str, spec: str) -> float | Bound:
        """The spec of the joint from an instance to its parent; a tied instance's is
        its source's, a fixed axis angle mirrored (a searched one is the source's slot).
        A spec its kind has no use for (``UNUSED_JOINT_SPECS``) is a placeholder: a
        continuous joint's limits -pi and pi, a fixed joint's axis along its parent
        (theta 0) and its motor's numbers their given value or lower bound."""
        if spec in UNUSED_JOINT_SPECS.get(self.joint_kind(instance_name), ()):
            if spec in _PLACEHOLDERS:
                return _PLACEHOLDERS[spec]
            given = self._joint_spec(instance_name, spec)
            return given.low if isinstance(given, Bound) else given
        return self._joint_spec(instance_name, spec)

    def _joint_spec(self, instance_name: str, spec: str) -> float | Bound:
        tie = self.tie(instance_name)
        own = self.instance(instance_name).joint_overrides
        if tie is not None and spec not in own:
            value = self._joint_spec(tie.source, spec)
            return value if isinstance(value, Bound) else mirrored_angle(spec, value, tie)
        instance = self.instance(instance_name)
        if spec in instance.joint_overrides:
            return instance.joint_overrides[spec]
        return getattr(self.joint, spec)

    def tree_structures(self) -> list[list[Edge]]:
        """The candidate structures as edge lists (``"all"`` enumerated, deterministic)."""
        if self._trees is None:
            if self.structures == "all":
                names = [instance.name for instance in self.instances]
                self._trees = list(_all_trees(names))
            else:
                self._trees = [[(p, c) for p, c in edges] for edges in self.structures]
        return self._trees

    def free_specs(self) -> list[tuple[str, Bound]]:
        """The free specs' keys in spec-vector order, with their Bounds.

        A part slot exists when its instance is in some structure and its spec is a
        Bound; a joint slot when its instance is a child in some structure. A tied
        instance's specs are its source's slots, which exist when either would; its
        own searched ``position`` is its only slot.
        """
        structures = self.tree_structures()
        members: set[str] = set()
        children: set[str] = set()
        for edges in structures:
            for parent, child in edges:
                members.update(with_tie_sources((parent, child), self._ties))
                children.update(with_tie_sources((child,), self._ties))
        slots: list[tuple[str, Bound]] = []
        for instance in self.instances:
            if instance.name not in members or instance.name in self._ties:
                continue
            slots += self._choice_slots(instance.name, "part")
            for spec in PART_SPECS:
                if self.catalogue_sets(instance.name, spec):
                    continue
                value = self.part_spec(instance.name, spec)
                if isinstance(value, Bound):
                    slots.append((f"{instance.name}.{spec}", value))
        for instance in self.instances:
            if instance.name not in children:
                continue
            if instance.name not in self._ties:
                slots += self._choice_slots(instance.name, "joint")
            for spec in JOINT_SPECS:
                if instance.name in self._ties and spec not in instance.joint_overrides:
                    continue
                if self.catalogue_sets(instance.name, f"joint.{spec}"):
                    continue
                value = self.joint_spec(instance.name, spec)
                if isinstance(value, Bound):
                    slots.append((f"{instance.name}.joint.{spec}", value))
        return slots

    def _choice_slots(
        self, instance_name: str, kind: Literal["part", "joint"]
    ) -> list[tuple[str, Bound]]:
        """The searched entries of the catalogue an instance's part or joint chooses
        from (``adclient.catalogues``), named ``<instance>.choice.<entry>`` and
        ``<instance>.joint.choice.<entry>``."""
        chosen = self.chosen_catalogue(instance_name, kind)
        if chosen is None:
            return []
        owner = instance_name if kind == "part" else f"{instance_name}.joint"
        return [
            (f"{owner}.choice.{slot.key}", Bound(low=slot.low, high=slot.high, log=slot.log))
            for slot in choice_slots(self.catalogues[chosen])
        ]

    def spec_slots(self) -> tuple[list[str], list[tuple[float, float]]]:
        """Free spec keys in spec-vector order, and their physical (low, high).

        The ranges are the values a spec takes, log-scaled or not: what a person
        reads and what bounds checks compare with. How a slot is normalised (its
        ``log``) is in ``free_specs`` and ``adclient.decode.SpecLayout``.
        """
        slots = self.free_specs()
        return [key for key, _ in slots], [(bound.low, bound.high) for _, bound in slots]


def with_tie_sources(names: Iterable[str], ties: Mapping[str, Tie]) -> set[str]:
    """``names`` and the sources of the tied instances among them: the instances whose
    spec slots they use."""
    names = set(names)
    return names | {ties[name].source for name in names if name in ties}


def _check_mass_specs(
    mass: float | Bound | None, density: float | Bound | None, where: str, fix: str
) -> None:
    """A link's mass is given once: by ``mass`` or by ``density``, not both, not neither."""
    if mass is not None and density is not None:
        raise ValueError(
            f"{where} gives both mass ({_show(mass)}) and density ({_show(density)}); "
            f"a link's mass is its mass or its density times its volume: {fix}"
        )
    if mass is None and density is None:
        raise ValueError(
            f"{where} gives neither mass nor density; give one (mass in kg, or density "
            "in kg/m^3 for a mass of density times the link's volume)"
        )


def _valid_name(name: str) -> bool:
    return re.fullmatch(NAME_PATTERN, name) is not None


def _check_tree(edges: list[Edge], names: set[str], where: str) -> None:
    """A structure is a rooted tree: >= 1 edge, one parent per child, one root, connected."""
    if not edges:
        raise ValueError(f"{where}: a structure needs at least one edge (two links)")
    parent_of: dict[str, str] = {}
    nodes: list[str] = []
    for number, (parent, child) in enumerate(edges):
        for name in (parent, child):
            if name not in names:
                raise ValueError(
                    f"{where}[{number}]: unknown instance {name!r} "
                    f"(instances: {', '.join(sorted(names))})"
                )
            if name not in nodes:
                nodes.append(name)
        if parent == child:
            raise ValueError(f"{where}[{number}]: edge joins {parent!r} to itself")
        if child in parent_of:
            raise ValueError(
                f"{where}: not a tree: {child!r} has two parents "
                f"({parent_of[child]!r} and {parent!r})"
            )
        parent_of[child] = parent
    roots = [name for name in nodes if name not in parent_of]
    if len(roots) != 1:
        raise ValueError(
            f"{where}: not a tree: it has no root (a cycle)"
            if not roots
            else f"{where}: not a tree: several roots ({', '.join(map(repr, roots))}), "
            "so it is not connected"
        )
    for start in parent_of:
        seen = {start}
        node = start
        while node in parent_of:
            node = parent_of[node]
            if node in seen:
                raise ValueError(f"{where}: not a tree: a cycle through {node!r}")
            seen.add(node)


def _all_trees(names: list[str]) -> Iterator[list[Edge]]:
    """Every labelled tree over ``names`` (Pruefer sequences in lexicographic order),
    rooted at ``names[0]``, edges listed breadth-first with children in name order."""
    n = len(names)
    if n == 2:
        yield [(names[0], names[1])]
        return
    for sequence in itertools.product(range(n), repeat=n - 2):
        adjacency: list[list[int]] = [[] for _ in range(n)]
        for u, v in _pruefer_edges(list(sequence), n):
            adjacency[u].append(v)
            adjacency[v].append(u)
        edges: list[Edge] = []
        visited = {0}
        frontier = [0]
        while frontier:
            following: list[int] = []
            for node in frontier:
                for neighbour in sorted(adjacency[node]):
                    if neighbour not in visited:
                        visited.add(neighbour)
                        edges.append((names[node], names[neighbour]))
                        following.append(neighbour)
            frontier = following
        yield edges


def _pruefer_edges(sequence: list[int], n: int) -> list[tuple[int, int]]:
    degree = [1] * n
    for node in sequence:
        degree[node] += 1
    leaves = [node for node in range(n) if degree[node] == 1]
    heapq.heapify(leaves)
    edges: list[tuple[int, int]] = []
    for node in sequence:
        leaf = heapq.heappop(leaves)
        edges.append((leaf, node))
        degree[node] -= 1
        if degree[node] == 1:
            heapq.heappush(leaves, node)
    u, v = heapq.heappop(leaves), heapq.heappop(leaves)
    edges.append((u, v))
    return edges


class Link(BaseModel):
    """One link of a design. ``mass`` is what it weighs (kg), whatever gave it: its
    ``mass`` spec, or ``density`` (kg/m^3, then also set) times its volume
    (``link_mass``); the URDF writer and the simulator use ``mass``."""

    name: str
    shape: Shape
    length: float
    radius: float
    mass: float
    density: float | None = None
    choice: str | None = None
    """The catalogue component it is, when its part chooses one."""

    @model_serializer(mode="wrap")
    def _density_when_set(self, handler: SerializerFunctionWrapHandler) -> dict[str, Any]:
        data: dict[str, Any] = handler(self)
        _drop_unset(data, "density", "choice")
        return data


class Joint(BaseModel):
    name: str
    parent: str
    child: str
    axis: tuple[float, float, float]
    axis_theta: float
    axis_phi: float
    position: float
    lower: float
    upper: float
    effort: float
    velocity: float
    choice: str | None = None
    """The catalogue component it is, when the joint chooses one."""
    kind: JointKind = "revolute"
    offset_roll: float | None = None
    offset_pitch: float | None = None
    offset_yaw: float | None = None
    """How its frame is turned on its parent (``OFFSET_SPECS``); None: its space turns
    no joint."""

    @property
    def offset(self) -> tuple[float, float, float]:
        """(roll, pitch, yaw), 0 where not set."""
        return (self.offset_roll or 0.0, self.offset_pitch or 0.0, self.offset_yaw or 0.0)

    @model_serializer(mode="wrap")
    def _set_fields_only(self, handler: SerializerFunctionWrapHandler) -> dict[str, Any]:
        """``choice`` only when set, ``kind`` only when not revolute: a design's JSON is
        what it was before them."""
        data: dict[str, Any] = handler(self)
        _drop_unset(data, "choice", *OFFSET_SPECS)
        if data.get("kind") == "revolute":
            del data["kind"]
        return data


class Design(BaseModel):
    """One concrete robot: a tree of links joined by revolute joints."""

    structure_index: int
    root: str
    links: list[Link]
    joints: list[Joint]

    def edges(self) -> list[Edge]:
        return [(joint.parent, joint.child) for joint in self.joints]


class Representation(BaseModel):
    """What turns a search vector back into a design, computed once per study.

    ``identity``: one structure; the vector is the spec vector normalised to [0, 1].
    ``fused``: several structures; the vector lives in the MDS embedding of the
    fused distances, decoded by nearest reference design plus an affine map.
    ``onehot``: several structures, plain encoding: one [0, 1] coordinate per
    structure (the largest wins, ties to the first), then the normalised spec vector.
    ``mixed``: several structures; the vector is the structure index (searched in
    [-0.5, S - 0.5] and rounded, so every structure owns an equal share) followed by
    the normalised spec vector, decoded by identity. ``structure_coords`` (S x k)
    places the structures in the fused geometry (the proposer's structure kernel).

    ``affine[s]`` is a ``(dim + 1) x p`` matrix: the normalised spec vector of
    structure ``s`` at search vector ``v`` is ``[v, 1] @ affine[s]``, clipped to
    [0, 1]. ``ref_coords`` (M x dim) and ``ref_structure`` (M) are the reference
    designs' coordinates and structure indices.

    ``spec_low``/``spec_high`` are the free specs' physical ranges, for reading; the
    decoder takes each slot's scale (linear, or ``log``) from the space's Bounds, which
    it always has (``adclient.decode.spec_layout``), so a representation's JSON is the
    same for log and linear specs.
    """

    kind: Literal["identity", "mixed", "fused", "onehot"]
    spec_names: list[str]
    spec_low: list[float]
    spec_high: list[float]
    structures: list[list[Edge]]
    bounds: list[list[float]] = Field(description="search box, [lows, highs]")
    ref_coords: list[list[float]] = Field(default_factory=list)
    ref_structure: list[int] = Field(default_factory=list)
    affine: list[list[list[float]]] = Field(default_factory=list)
    structure_coords: list[list[float]] = Field(default_factory=list)
    info: dict[str, float | int | str] = Field(default_factory=dict)
