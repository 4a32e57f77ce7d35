"""A URDF read into what a simulation worker builds a robot from, and checked first.

A template study's robot is the user's own URDF (expanded from their xacro), not one
written from a design, so the worker reads its links, collision shapes and joints from
the text. :func:`read_urdf` checks what a robot needs before any engine sees it: a tree
of uniquely named links, joints of a kind the worker drives (revolute, continuous,
prismatic, fixed) with the limits a motor needs, shapes of primitives (box, cylinder,
sphere, capsule: a template travels as text, so a mesh file it names would not), finite
numbers. A problem is a :class:`URDFModelError` naming the element and, where the
URDF's text has it, the line.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
import xml.parsers.expat
from dataclasses import dataclass, field
from typing import Literal

JointKind = Literal["revolute", "continuous", "prismatic", "fixed"]
DRIVEN_KINDS: tuple[str, ...] = ("revolute", "continuous", "prismatic")
"""Joint kinds the worker drives (one action per joint); fixed joints only hold links."""

ShapeKind = Literal["box", "cylinder", "sphere", "capsule"]


class URDFModelError(ValueError):
    """A URDF the worker cannot build a robot from; the message names what and where."""


@dataclass(frozen=True)
class Origin:
    xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class Shape:
    """One collision (or, without any, visual) primitive of a link, in the link frame.

    ``size``: a box's three sides; a cylinder's or capsule's (radius, length), the
    length along the shape frame's z; a sphere's (radius,)."""

    kind: ShapeKind
    size: tuple[float, ...]
    origin: Origin = field(default_factory=Origin)


@dataclass(frozen=True)
class UrdfLink:
    name: str
    mass: float
    """Its ``<inertial><mass>``; without ``<inertial>``, PyBullet's default (1 kg)."""
    shapes: tuple[Shape, ...]
    inertial: Origin = field(default_factory=Origin)
    """Its ``<inertial><origin>``: where its centre of mass is in the link frame."""


@dataclass(frozen=True)
class UrdfJoint:
    name: str
    kind: JointKind
    parent: str
    child: str
    axis: tuple[float, float, float]
    lower: float
    upper: float
    effort: float
    velocity: float
    origin: Origin = field(default_factory=Origin)
    """The child's frame on its parent's at position 0 (its ``<origin>``); ``axis`` is
    in the child's frame."""


@dataclass(frozen=True)
class UrdfModel:
    name: str
    root: str
    links: dict[str, UrdfLink]
    joints: tuple[UrdfJoint, ...]

    @property
    def driven(self) -> list[UrdfJoint]:
        return [joint for joint in self.joints if joint.kind in DRIVEN_KINDS]

    @property
    def mass(self) -> float:
        """The sum of the links' masses as PyBullet simulates them (kg)."""
        return math.fsum(link.mass for link in self.links.values())


def _lines(text: str) -> dict[tuple[str, str], int]:
    """(tag, name) -> the line of that element, for messages (minidom keeps no lines;
    expat's parser does)."""
    found: dict[tuple[str, str], int] = {}
    parser = xml.parsers.expat.ParserCreate()

    def start(tag: str, attributes: dict[str, str]) -> None:
        name = attributes.get("name")
        if name is not None:
            found.setdefault((tag, name), parser.CurrentLineNumber)

    parser.StartElementHandler = start
    parser.Parse(text, True)
    return found


def read_urdf(text: str, *, lines_from: str | None = None) -> UrdfModel:
    """The robot a URDF describes; URDFModelError naming the first problem and its
    line, in ``lines_from`` when given (the template this URDF was expanded from: an
    element whose name the template spells out)."""
    try:
        root = ET.fromstring(text)
    except ET.ParseError as error:
        line, column = error.position
        raise URDFModelError(f"line {line}, column {column}: not well-formed XML") from None
    try:
        lines = _lines(text if lines_from is None else lines_from)
    except xml.parsers.expat.ExpatError:  # a template only xacro reads
        lines = {}

    def where(tag: str, name: str) -> str:
        line = lines.get((tag, name))
        return f"{tag} {name!r}" + (f" (line {line})" if line else "")

    if root.tag != "robot":
        raise URDFModelError(f"the root element is <{root.tag}>, not <robot>")
    links: dict[str, UrdfLink] = {}
    for element in root.findall("link"):
        name = element.get("name") or ""
        if not name:
            raise URDFModelError("a <link> has no name")
        if name in links:
            raise URDFModelError(f"{where('link', name)}: two links of that name")
        inertial = element.find("inertial")
        links[name] = UrdfLink(
            name,
            _mass(element, where("link", name)),
            _shapes(element, where("link", name)),
            Origin() if inertial is None else _origin(inertial, where("link", name)),
        )
    if not links:
        raise URDFModelError("the robot has no <link>")
    joints: list[UrdfJoint] = []
    parent_of: dict[str, str] = {}
    for element in root.findall("joint"):
        name = element.get("name") or ""
        if not name:
            raise URDFModelError("a <joint> has no name")
        joint = _joint(element, where("joint", name))
        for end, link in (("parent", joint.parent), ("child", joint.child)):
            if link not in links:
                raise URDFModelError(f"{where('joint', name)}: its {end} {link!r} is no link")
        if joint.child in parent_of:
            raise URDFModelError(
                f"{where('joint', name)}: link {joint.child!r} has two parents "
                f"({parent_of[joint.child]!r} and {joint.parent!r})"
            )
        if any(other.name == name for other in joints):
            raise URDFModelError(f"{where('joint', name)}: two joints of that name")
        parent_of[joint.child] = joint.parent
        joints.append(joint)
    roots = [name for name in links if name not in parent_of]
    if len(roots) != 1:
        raise URDFModelError(
            "the links form no tree: "
            + (f"{len(roots)} links have no parent ({', '.join(roots)})" if roots else "a cycle")
        )
    for link in links:  # every link reaches the root, or the parents go round
        seen = {link}
        while link in parent_of:
            link = parent_of[link]
            if link in seen:
                raise URDFModelError(f"the links form no tree: a cycle through {link!r}")
            seen.add(link)
    model = UrdfModel(root.get("name") or "robot", roots[0], links, tuple(joints))
    if not model.driven:
        raise URDFModelError("the robot has no joint to drive (revolute, continuous, prismatic)")
    return model


def _float(element: ET.Element, attribute: str, what: str, default: float | None = None) -> float:
    raw = element.get(attribute)
    if raw is None:
        if default is None:
            raise URDFModelError(f"{what}: <{element.tag}> needs {attribute}")
        return default
    try:
        value = float(raw)
    except ValueError:
        raise URDFModelError(f"{what}: <{element.tag} {attribute}={raw!r}> is no number") from None
    if not math.isfinite(value):
        raise URDFModelError(f"{what}: <{element.tag} {attribute}={raw!r}> is not finite")
    return value


def _vector(element: ET.Element | None, attribute: str, what: str, n: int = 3) -> tuple[float, ...]:
    raw = None if element is None else element.get(attribute)
    if raw is None:
        return (0.0,) * n
    try:
        values = tuple(float(part) for part in raw.split())
    except ValueError:
        raise URDFModelError(f"{what}: {attribute}={raw!r} is not {n} numbers") from None
    if len(values) != n or not all(math.isfinite(v) for v in values):
        raise URDFModelError(f"{what}: {attribute}={raw!r} is not {n} finite numbers")
    return values


def _origin(element: ET.Element, what: str) -> Origin:
    origin = element.find("origin")
    xyz = _vector(origin, "xyz", what)
    rpy = _vector(origin, "rpy", what)
    return Origin((xyz[0], xyz[1], xyz[2]), (rpy[0], rpy[1], rpy[2]))


DEFAULT_MASS = 1.0
"""What PyBullet simulates a link without ``<inertial>`` as (kg; it warns and uses 1)."""


def _mass(link: ET.Element, what: str) -> float:
    if link.find("inertial") is None:
        return DEFAULT_MASS
    mass = link.find("inertial/mass")
    if mass is None:
        return 0.0
    value = _float(mass, "value", what)
    if value < 0:
        raise URDFModelError(f"{what}: its mass is {value}, below 0")
    return value


def _shapes(link: ET.Element, what: str) -> tuple[Shape, ...]:
    elements = link.findall("collision") or link.findall("visual")
    shapes = []
    for element in elements:
        geometry = element.find("geometry")
        primitive = None if geometry is None else next(iter(geometry), None)
        if primitive is None:
            raise URDFModelError(f"{what}: a <{element.tag}> has no geometry")
        kind = primitive.tag
        if kind == "box":
            size = _vector(primitive, "size", what)
        elif kind in ("cylinder", "capsule"):
            size = (_float(primitive, "radius", what), _float(primitive, "length", what))
        elif kind == "sphere":
            size = (_float(primitive, "radius", what),)
        else:
            raise URDFModelError(
                f"{what}: its geometry is <{kind}>; a template's shapes are box, cylinder, "
                "sphere or capsule (it travels as text: a mesh file would not go with it)"
            )
        if not all(value > 0 for value in size):
            raise URDFModelError(f"{what}: its <{kind}> has a size that is not above 0")
        shapes.append(Shape(kind, size, _origin(element, what)))  # type: ignore[arg-type]
    return tuple(shapes)


def _joint(element: ET.Element, what: str) -> UrdfJoint:
    kind = element.get("type")
    if kind not in ("revolute", "continuous", "prismatic", "fixed"):
        raise URDFModelError(
            f"{what}: type {kind!r}; the worker drives revolute, continuous and prismatic "
            "joints and holds fixed ones"
        )
    ends = {}
    for end in ("parent", "child"):
        tag = element.find(end)
        if tag is None or not tag.get("link"):
            raise URDFModelError(f"{what}: it needs <{end} link=...>")
        ends[end] = tag.get("link") or ""
    axis = (
        _vector(element.find("axis"), "xyz", what)
        if element.find("axis") is not None
        else (1.0, 0.0, 0.0)
    )
    norm = math.sqrt(sum(v * v for v in axis))
    if kind != "fixed" and norm == 0:
        raise URDFModelError(f"{what}: its axis is zero")
    limit = element.find("limit")
    lower = upper = effort = velocity = 0.0
    if kind in DRIVEN_KINDS:
        if limit is None:
            raise URDFModelError(f"{what}: a {kind} joint needs <limit effort=... velocity=...>")
        effort = _float(limit, "effort", what)
        velocity = _float(limit, "velocity", what)
        if not (effort > 0 and velocity > 0):
            raise URDFModelError(
                f"{what}: its limit needs effort > 0 and velocity > 0 (a motor), "
                f"got effort {effort} and velocity {velocity}"
            )
        if kind == "continuous":
            lower, upper = -math.pi, math.pi
        else:
            lower = _float(limit, "lower", what, default=0.0)
            upper = _float(limit, "upper", what, default=0.0)
            if not lower < upper:
                raise URDFModelError(
                    f"{what}: its limit needs lower < upper, got {lower} and {upper}"
                )
    return UrdfJoint(
        name=element.get("name") or "",
        kind=kind,  # type: ignore[arg-type]
        parent=ends["parent"],
        child=ends["child"],
        axis=(axis[0] / (norm or 1), axis[1] / (norm or 1), axis[2] / (norm or 1)),
        lower=lower,
        upper=upper,
        effort=effort,
        velocity=velocity,
        origin=_origin(element, what),
    )
