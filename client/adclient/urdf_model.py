"""A URDF read into what a simulation worker builds a robot from, and checked first.

A template study's robot is the user's own URDF (expanded from their xacro), not one
written from a design, so the worker reads its links, collision shapes and joints from
the text. :func:`read_urdf` checks what a robot needs before any engine sees it: a tree
of uniquely named links, joints of a kind the worker drives (revolute, continuous,
prismatic, fixed) with the limits a motor needs, collision and visual shapes alike of
primitives (box, cylinder, sphere, capsule: a template travels as text, so a mesh file
it names would not, and no engine is handed a path on the worker), materials of colour
alone (no texture file), finite numbers. The text is read as data
(:mod:`adclient.xml_data`). A problem is a :class:`URDFModelError` naming the element
and, where the URDF's text has it, the line.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from typing import Literal

from adclient.xml_data import XMLDataError, parse_xml

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


def read_urdf(text: str, *, lines_from: str | None = None) -> UrdfModel:
    """The robot a URDF describes; URDFModelError naming the first problem and its
    line, in ``lines_from`` when given (the template this URDF was expanded from: an
    element whose name the template spells out). The text is read as data
    (:func:`adclient.xml_data.parse_xml`: no DTD, entity or processing instruction), in
    time linear in its size."""
    try:
        root, lines = parse_xml(text)
    except XMLDataError as error:
        raise URDFModelError(str(error)) from None
    if lines_from is not None:
        try:
            _, lines = parse_xml(lines_from)
        except XMLDataError:  # a template only xacro reads
            lines = {}

    def where(tag: str, name: str) -> str:
        line = lines.get((tag, name))
        return f"{tag} {name!r}" + (f" (line {line})" if line else "")

    if root.tag != "robot":
        raise URDFModelError(f"the root element is <{root.tag}>, not <robot>")
    for material in root.findall("material"):
        _check_material(material, where("material", material.get("name") or ""))
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
    joint_names: set[str] = set()
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
        if name in joint_names:
            raise URDFModelError(f"{where('joint', name)}: two joints of that name")
        joint_names.add(name)
        parent_of[joint.child] = joint.parent
        joints.append(joint)
    roots = [name for name in links if name not in parent_of]
    if len(roots) != 1:
        raise URDFModelError(
            "the links form no tree: "
            + (f"{len(roots)} links have no parent ({_listed(roots)})" if roots else "a cycle")
        )
    _check_tree(roots[0], links, joints)
    model = UrdfModel(root.get("name") or "robot", roots[0], links, tuple(joints))
    if not model.driven:
        raise URDFModelError("the robot has no joint to drive (revolute, continuous, prismatic)")
    return model


def _listed(names: list[str], most: int = 10) -> str:
    shown = ", ".join(names[:most])
    return shown + (f" and {len(names) - most} more" if len(names) > most else "")


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
    """The link's collision primitives, or without any its visual ones; both are
    checked alike (a primitive each, no file named: see :func:`_primitive`)."""
    collisions = [_shape(element, what) for element in link.findall("collision")]
    visuals = [_shape(element, what) for element in link.findall("visual")]
    for material in link.iterfind("visual/material"):
        _check_material(material, what)
    return tuple(collisions or visuals)


def _shape(element: ET.Element, what: str) -> Shape:
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
            f"{what}: its geometry is <{kind}> (in a <{element.tag}>); a template's shapes, "
            "visual and collision alike, are box, cylinder, sphere or capsule (it travels as "
            "text: a mesh file would not go with it, and no file on the worker is read)"
        )
    if not all(value > 0 for value in size):
        raise URDFModelError(f"{what}: its <{kind}> has a size that is not above 0")
    return Shape(kind, size, _origin(element, what))  # type: ignore[arg-type]


def _check_material(material: ET.Element, what: str) -> None:
    """A material is a name and a colour: a texture would be a file on the worker."""
    for child in material:
        if child.tag != "color":
            raise URDFModelError(
                f"{what}: its material has <{child.tag}>; a material is a <color> (no "
                "texture: it would be a file on the worker)"
            )


def _check_tree(root: str, links: dict[str, UrdfLink], joints: list[UrdfJoint]) -> None:
    """Every link hangs from ``root``: each has one parent at most (checked), so the
    links not reached from the root go round in a cycle. One walk, linear in links."""
    children: dict[str, list[str]] = {}
    for joint in joints:
        children.setdefault(joint.parent, []).append(joint.child)
    reached = {root}
    stack = [root]
    while stack:
        for child in children.get(stack.pop(), ()):
            if child not in reached:
                reached.add(child)
                stack.append(child)
    if len(reached) != len(links):
        stray = next(name for name in links if name not in reached)
        raise URDFModelError(f"the links form no tree: a cycle through {stray!r}")


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
