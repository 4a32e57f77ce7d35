"""Design -> URDF, written with xml.etree so no user text is ever spliced into markup.

Follows the geometry conventions of ``adclient.design``: each link frame sits at the
joint to its parent, the link's shape spans z in [0, length], a child's joint sits
at ``position * parent.length`` on the parent's z axis, turned by its offset (rpy;
an identity rotation without one).
Inertias are those of a solid, uniform cylinder or box of the link's mass, about its
centre; the inertial frame sits at the shape's centre, unrotated. The mass written is
``Link.mass``: the link's ``mass`` spec, or its ``density`` times its volume when its
part gives density (``adclient.specs.link_mass``), so both the mass and the inertia
tensor follow the geometry for such a link.
"""

from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET

from adclient.designs import Design, Link
from adclient.specs import NAME_PATTERN

_COLOURS = (
    "0.86 0.37 0.34 1",
    "0.33 0.56 0.85 1",
    "0.42 0.74 0.42 1",
    "0.93 0.71 0.29 1",
    "0.60 0.44 0.77 1",
    "0.35 0.75 0.75 1",
)


class URDFError(ValueError):
    """A design that cannot be written as a valid URDF (names, numbers, tree shape)."""


def _check_name(name: str, what: str) -> str:
    if not isinstance(name, str) or re.fullmatch(NAME_PATTERN, name) is None:
        raise URDFError(
            f"{what} name {name!r} is not allowed: it must match {NAME_PATTERN} "
            "(a letter, then up to 63 letters, digits, '_' or '-')"
        )
    return name


def _number(value: float, what: str, *, positive: bool = False) -> str:
    value = float(value)
    if not math.isfinite(value):
        raise URDFError(f"{what} must be a finite number, got {value!r}")
    if positive and not value > 0:
        raise URDFError(f"{what} must be > 0, got {value!r}")
    return repr(value)


def _numbers(values: tuple[float, ...] | list[float], what: str) -> str:
    return " ".join(_number(value, what) for value in values)


def link_inertia(link: Link) -> tuple[float, float, float]:
    """(ixx, iyy, izz) about the centre of mass, z along the link (a capsule's: a
    cylinder's of its whole mass and length, a slight understatement)."""
    m, r, h = link.mass, link.radius, link.length
    if link.shape == "box":
        side = 2 * r
        ixx = m * (side**2 + h**2) / 12
        return ixx, ixx, m * (side**2 + side**2) / 12
    ixx = m * (3 * r**2 + h**2) / 12
    return ixx, ixx, m * r**2 / 2


def design_mass(design: Design) -> float:
    """The robot's total mass as built (kg): the sum of its links' masses.

    Each link's mass is ``Link.mass``, written as the link's ``<inertial><mass>``, so
    this is also the sum of the masses a simulator loading the URDF simulates. That is
    the link's ``mass`` spec, or, for a part that gives ``density`` instead, density
    times the link's volume (a solid cylinder: ``density * pi r^2 length``): then a
    longer or thicker link weighs more."""
    return math.fsum(float(link.mass) for link in design.links)


def design_link_length(design: Design) -> float:
    """Total length of the robot's links (m): the sum of each link's ``length``, the
    span of its cylinder or box along its own axis (radii not counted; a joint placed
    before its parent's far end does not shorten the parent)."""
    return math.fsum(float(link.length) for link in design.links)


def _geometry(parent: ET.Element, link: Link, *, visual: bool = False) -> None:
    """The link's shape in ``parent`` (a visual or collision element, its origin at the
    shape's centre). A capsule is PyBullet's ``<capsule>``; seen, it is a cylinder and
    two balls, which every URDF viewer draws (``<capsule>`` is no URDF standard)."""
    geometry = ET.SubElement(parent, "geometry")
    what = f"link {link.name!r}"
    if link.shape == "capsule" and not visual:
        ET.SubElement(
            geometry,
            "capsule",
            radius=_number(link.radius, f"{what} radius", positive=True),
            length=_number(link.length, f"{what} length", positive=True),
        )
    elif link.shape == "box":
        side = 2 * link.radius
        size = (side, side, link.length)
        ET.SubElement(geometry, "box", size=_numbers(size, f"link {link.name!r} size"))
    else:
        ET.SubElement(
            geometry,
            "cylinder",
            radius=_number(link.radius, f"link {link.name!r} radius", positive=True),
            length=_number(link.length, f"link {link.name!r} length", positive=True),
        )


def _check_tree(design: Design) -> None:
    names = [link.name for link in design.links]
    if len(set(names)) != len(names):
        raise URDFError(f"duplicate link names in {names}")
    joint_names = [joint.name for joint in design.joints]
    if len(set(joint_names)) != len(joint_names):
        raise URDFError(f"duplicate joint names in {joint_names}")
    known = set(names)
    parent_of: dict[str, str] = {}
    for joint in design.joints:
        for end in (joint.parent, joint.child):
            if end not in known:
                raise URDFError(f"joint {joint.name!r} names unknown link {end!r}")
        if joint.child in parent_of:
            raise URDFError(f"link {joint.child!r} has two parent joints")
        parent_of[joint.child] = joint.parent
    roots = [name for name in names if name not in parent_of]
    if roots != [design.root]:
        raise URDFError(f"the design is not one tree rooted at {design.root!r} (roots: {roots})")
    for start in parent_of:
        node, steps = start, 0
        while node in parent_of:
            node, steps = parent_of[node], steps + 1
            if steps > len(names):
                raise URDFError(f"joints form a cycle through {start!r}")


def design_to_urdf(design: Design, robot_name: str = "robot") -> str:
    """The URDF document of a design (a string starting with the XML declaration)."""
    _check_name(robot_name, "robot")
    for link in design.links:
        _check_name(link.name, "link")
    for joint in design.joints:
        _check_name(joint.name, "joint")
    _check_tree(design)
    lengths = {link.name: link.length for link in design.links}

    robot = ET.Element("robot", name=robot_name)
    for index, link in enumerate(design.links):
        what = f"link {link.name!r}"
        _number(link.length, f"{what} length", positive=True)
        _number(link.radius, f"{what} radius", positive=True)
        centre = _numbers((0.0, 0.0, link.length / 2), f"{what} centre")
        element = ET.SubElement(robot, "link", name=link.name)
        inertial = ET.SubElement(element, "inertial")
        ET.SubElement(inertial, "origin", xyz=centre, rpy="0 0 0")
        ET.SubElement(inertial, "mass", value=_number(link.mass, f"{what} mass", positive=True))
        ixx, iyy, izz = link_inertia(link)
        ET.SubElement(
            inertial,
            "inertia",
            ixx=_number(ixx, f"{what} inertia"),
            ixy="0",
            ixz="0",
            iyy=_number(iyy, f"{what} inertia"),
            iyz="0",
            izz=_number(izz, f"{what} inertia"),
        )
        visual = ET.SubElement(element, "visual")
        ET.SubElement(visual, "origin", xyz=centre, rpy="0 0 0")
        _geometry(visual, link, visual=True)
        material = ET.SubElement(visual, "material", name=f"{link.name}_colour")
        ET.SubElement(material, "color", rgba=_COLOURS[index % len(_COLOURS)])
        if link.shape == "capsule":  # its two ends, seen
            for end in (0.0, link.length):
                ball = ET.SubElement(element, "visual")
                ET.SubElement(ball, "origin", xyz=_numbers((0.0, 0.0, end), what), rpy="0 0 0")
                sphere = ET.SubElement(ET.SubElement(ball, "geometry"), "sphere")
                sphere.set("radius", _number(link.radius, f"{what} radius", positive=True))
                colour = ET.SubElement(ball, "material", name=f"{link.name}_colour")
                ET.SubElement(colour, "color", rgba=_COLOURS[index % len(_COLOURS)])
        collision = ET.SubElement(element, "collision")
        ET.SubElement(collision, "origin", xyz=centre, rpy="0 0 0")
        _geometry(collision, link)

    for joint in design.joints:
        what = f"joint {joint.name!r}"
        norm = math.sqrt(sum(float(component) ** 2 for component in joint.axis))
        if not (math.isfinite(norm) and norm > 1e-9):
            raise URDFError(f"{what} axis {joint.axis} has no direction")
        if not 0.0 <= joint.position <= 1.0:
            raise URDFError(f"{what} position {joint.position} must lie in [0, 1]")
        if not joint.lower <= joint.upper:
            raise URDFError(f"{what} lower limit {joint.lower} exceeds upper {joint.upper}")
        element = ET.SubElement(robot, "joint", name=joint.name, type=joint.kind)
        ET.SubElement(element, "parent", link=joint.parent)
        ET.SubElement(element, "child", link=joint.child)
        offset = joint.position * lengths[joint.parent]
        ET.SubElement(
            element,
            "origin",
            xyz=_numbers((0.0, 0.0, offset), f"{what} origin"),
            rpy=_numbers(joint.offset, f"{what} offset") if any(joint.offset) else "0 0 0",
        )
        if joint.kind == "fixed":
            continue
        axis = tuple(float(component) / norm for component in joint.axis)
        ET.SubElement(element, "axis", xyz=_numbers(axis, f"{what} axis"))
        limit = ET.SubElement(element, "limit")
        if joint.kind != "continuous":  # metres for a prismatic joint
            limit.set("lower", _number(joint.lower, f"{what} lower"))
            limit.set("upper", _number(joint.upper, f"{what} upper"))
        limit.set("effort", _number(joint.effort, f"{what} effort", positive=True))
        limit.set("velocity", _number(joint.velocity, f"{what} velocity", positive=True))
    ET.indent(robot)
    return '<?xml version="1.0"?>\n' + ET.tostring(robot, encoding="unicode") + "\n"
