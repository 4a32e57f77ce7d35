"""A typed Design as a MuJoCo model (MJCF), following the conventions of adclient.design.

Each link is a body whose frame sits at the joint to its parent; its shape spans z in
[0, length] (a cylinder of the link's radius, a box 2 radius wide, or a capsule) and its
mass is spread uniformly over the shape, as in the URDF the worker writes. A child body
sits at ``position * parent.length`` on its parent's z axis, unrotated, joined by a hinge
about the joint's axis within [lower, upper] (a continuous joint's all round), a slide
along it for a prismatic joint, or welded on for a fixed one. The root has no joint: it
is welded to the world at the origin, standing up. Each driven joint has a position servo
whose force is capped at the joint's effort (its velocity spec is not modelled). Links
touch the floor but not each other, as in adworker's PyBullet simulator. A site
``<link>_end`` marks each link's far end, and an optional ``target`` site (no collision)
marks a point for the picture.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from collections.abc import Sequence

from adclient.designs import Design, Joint, Link

SERVO_GAIN = 100.0
"""Position servo stiffness (N m / rad); its force is capped at the joint's effort."""
JOINT_DAMPING = 2.0
"""Joint damping (N m s / rad): the servo settles instead of ringing."""
COLOURS = ("0.86 0.37 0.34 1", "0.33 0.56 0.85 1", "0.42 0.74 0.42 1", "0.93 0.71 0.29 1")


def numbers(*values: float) -> str:
    return " ".join(repr(float(value)) for value in values)


def driven_joints(design: Design) -> list[Joint]:
    """The joints an action drives: all but the fixed ones."""
    return [joint for joint in design.joints if joint.kind != "fixed"]


def joint_range(joint: Joint) -> tuple[float, float]:
    """The joint's [lower, upper]; a joint without a proper range turns all the way round."""
    if joint.lower < joint.upper and joint.kind != "continuous":
        return joint.lower, joint.upper
    return -math.pi, math.pi


def design_to_mjcf(
    design: Design, *, time_step: float = 0.005, target: Sequence[float] | None = None
) -> str:
    """The MJCF document of a design; actuator i drives ``driven_joints(design)[i]``."""
    root = ET.Element("mujoco", model="robot")
    ET.SubElement(root, "compiler", angle="radian", autolimits="true", eulerseq="XYZ")
    ET.SubElement(root, "option", timestep=repr(time_step), integrator="implicitfast")
    world = ET.SubElement(root, "worldbody")
    ET.SubElement(world, "light", pos="0 0 3", dir="0 0 -1", directional="true")
    # The floor collides with links (contype 0, conaffinity 1); links with the floor only.
    floor = {"name": "floor", "type": "plane", "size": "5 5 0.1", "rgba": "0.8 0.8 0.8 1"}
    ET.SubElement(world, "geom", floor, contype="0")
    if target is not None:
        ET.SubElement(
            world, "site", name="target", pos=numbers(*target), size="0.03", rgba="1 0 0 1"
        )

    links = {link.name: link for link in design.links}
    children: dict[str, list[Joint]] = {}
    for joint in design.joints:
        children.setdefault(joint.parent, []).append(joint)

    def add(parent: ET.Element, link: Link, height: float, joint: Joint | None) -> None:
        body = ET.SubElement(parent, "body", name=link.name, pos=numbers(0, 0, height))
        if joint is not None and any(joint.offset):  # URDF's rpy: X, then Y, then Z, fixed
            body.set("euler", numbers(*joint.offset))
        if joint is not None and joint.kind != "fixed":  # a fixed child is welded on
            norm = math.sqrt(sum(component**2 for component in joint.axis))
            hinge = {
                "name": joint.name,
                "type": "slide" if joint.kind == "prismatic" else "hinge",
                "axis": numbers(*(component / norm for component in joint.axis)),
                "damping": repr(JOINT_DAMPING),
            }
            if joint.lower < joint.upper and joint.kind != "continuous":
                hinge["range"] = numbers(joint.lower, joint.upper)
            ET.SubElement(body, "joint", hinge)
        colour = COLOURS[design.links.index(link) % len(COLOURS)]
        shape = {"contype": "1", "conaffinity": "0", "mass": repr(link.mass), "rgba": colour}
        if link.shape == "box":
            size = numbers(link.radius, link.radius, link.length / 2)
            centre = numbers(0, 0, link.length / 2)
            ET.SubElement(body, "geom", shape, type="box", pos=centre, size=size)
        else:  # a capsule is MuJoCo's own: the cylinder with its end balls
            ends = numbers(0, 0, 0, 0, 0, link.length)
            kind = "capsule" if link.shape == "capsule" else "cylinder"
            ET.SubElement(body, "geom", shape, type=kind, fromto=ends, size=repr(link.radius))
        ET.SubElement(body, "site", name=f"{link.name}_end", pos=numbers(0, 0, link.length))
        for child in children.get(link.name, []):
            add(body, links[child.child], child.position * link.length, child)

    add(world, links[design.root], 0.0, None)
    actuators = ET.SubElement(root, "actuator")
    for joint in driven_joints(design):
        ET.SubElement(
            actuators,
            "position",
            joint=joint.name,
            kp=repr(SERVO_GAIN),
            forcerange=numbers(-joint.effort, joint.effort),
        )
    return ET.tostring(root, encoding="unicode")
