"""Where adworker's simulator puts a robot before its episodes: its spawn pose.

One pure function of the robot (``spawn_pose``), so the worker that places the robot
(``adworker.tasks.robot.Robot``) and the server that tells the dashboard where it is
(``GET /api/v1/trials/{id}/spawn``) compute the same pose and cannot disagree.

- A task with a fixed base (``TaskSpec.fixed_base``) leaves the root where its URDF
  puts it: its frame at the world origin, unturned.
- A free design (``lay_down``) lies on its side along world +x: the chain at rest (the
  root frame's +z) runs along +x, rolled about that line so the axis of the root's
  first joint is horizontal, and bending that joint lifts links off the ground (as
  anyone setting the robot down would place it). What the design then decides is how
  the other axes sit relative to that one: parallel ones fold the chain in a vertical
  plane, others twist it out of that plane.
- A free robot of the user's own URDF (a template's) stands as built: its root frame
  upright.

A free robot's base has its centre of mass over the world origin and its lowest point
``CLEARANCE`` above the ground (z = 0), with its joints where every episode starts
before its noise: each driven joint at 0, or the limit nearest 0. The lowest point is
each collision shape's own: a box's lowest corner, a cylinder's rim, a sphere's or
capsule's ball.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping

import numpy as np

from adclient.designs import Design, Link
from adclient.schemas.trials import Spawn
from adclient.urdf_model import Origin, Shape, UrdfJoint, UrdfLink, UrdfModel, read_urdf

CLEARANCE = 1e-4
"""How far above the ground a free robot's lowest point starts (m)."""

IDENTITY = (0.0, 0.0, 0.0, 1.0)


def rpy_rotation(rpy: tuple[float, float, float]) -> np.ndarray:
    """URDF's rpy as a matrix: fixed-axis roll about x, then pitch about y, then yaw
    about z."""
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = (
        math.cos(r),
        math.sin(r),
        math.cos(p),
        math.sin(p),
        math.cos(y),
        math.sin(y),
    )
    rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    return rz @ ry @ rx


def _about(axis: tuple[float, float, float], angle: float) -> tuple[float, ...]:
    """The quaternion (x, y, z, w) of a turn by ``angle`` about the unit ``axis``."""
    s = math.sin(angle / 2)
    return (axis[0] * s, axis[1] * s, axis[2] * s, math.cos(angle / 2))


def _product(a: tuple[float, ...], b: tuple[float, ...]) -> tuple[float, float, float, float]:
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    )


def _matrix(q: tuple[float, ...]) -> np.ndarray:
    x, y, z, w = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def design_model(design: Design) -> UrdfModel:
    """A design as its URDF (``adclient.urdf``) describes it, each joint's range as a
    simulator drives it (``Joint.limits``)."""
    lengths = {link.name: link.length for link in design.links}
    joints = []
    for joint in design.joints:
        norm = math.sqrt(sum(component * component for component in joint.axis))
        lower, upper = joint.limits
        joints.append(
            UrdfJoint(
                name=joint.name,
                kind=joint.kind,
                parent=joint.parent,
                child=joint.child,
                axis=(joint.axis[0] / norm, joint.axis[1] / norm, joint.axis[2] / norm),
                lower=lower,
                upper=upper,
                effort=joint.effort,
                velocity=joint.velocity,
                origin=Origin((0.0, 0.0, joint.position * lengths[joint.parent]), joint.offset),
            )
        )
    return UrdfModel(
        "robot",
        design.root,
        {link.name: _design_link(link) for link in design.links},
        tuple(joints),
    )


def _design_link(link: Link) -> UrdfLink:
    """Its shape spans z in [0, length] (``adclient.design``); its mass sits mid-way."""
    centre = Origin((0.0, 0.0, link.length / 2))
    if link.shape == "box":
        shape = Shape("box", (2 * link.radius, 2 * link.radius, link.length), centre)
    else:
        shape = Shape(link.shape, (link.radius, link.length), centre)
    return UrdfLink(link.name, link.mass, (shape,), centre)


def robot_spawn(design: Design | None, urdf: str | None, *, fixed_base: bool) -> Spawn:
    """A trial's robot's spawn pose: its design's, laid down, or, without one (a
    template study's), its URDF's as built (``read_urdf``: URDFModelError when it builds
    no robot)."""
    if design is not None:
        return spawn_pose(design_model(design), lay_down=True, fixed_base=fixed_base)
    if urdf is None:
        raise ValueError("a robot's spawn pose needs its design or its URDF")
    return spawn_pose(read_urdf(urdf), lay_down=False, fixed_base=fixed_base)


def spawn_pose(model: UrdfModel, *, lay_down: bool, fixed_base: bool) -> Spawn:
    """Where the simulator puts this robot (see the module docstring): a design's
    (``design_model``) laid down, a URDF's as built."""
    joints = {joint.name: min(max(0.0, joint.lower), joint.upper) for joint in model.driven}
    if fixed_base:
        return Spawn(fixed_base=True, position=(0.0, 0.0, 0.0), orientation=IDENTITY, joints=joints)
    orientation = _laid_down(model) if lay_down else IDENTITY
    rotation = _matrix(orientation)
    position = -rotation @ np.array(model.links[model.root].inertial.xyz)
    lowest = min(_lowest_points(model, rotation, position, joints))
    x, y, z = position.tolist()
    return Spawn(
        fixed_base=False,
        position=(x, y, z + CLEARANCE - lowest),
        orientation=orientation,
        joints=joints,
    )


def _laid_down(model: UrdfModel) -> tuple[float, float, float, float]:
    """The root frame's +x, +y, +z on world -z, +y, +x, then rolled about world x by
    atan2(ux, uy), which brings the first joint's axis u into the horizontal plane."""
    roll = 0.0
    first = next((joint for joint in model.joints if joint.parent == model.root), None)
    if first is not None:
        ux, uy, _ = rpy_rotation(first.origin.rpy) @ np.array(first.axis)
        if math.hypot(ux, uy) > 1e-6:
            roll = math.atan2(ux, uy)
    return _product(_about((1.0, 0.0, 0.0), roll), _about((0.0, 1.0, 0.0), math.pi / 2))


def link_frames(
    model: UrdfModel, rotation: np.ndarray, position: np.ndarray, joints: Mapping[str, float]
) -> Iterator[tuple[str, np.ndarray, np.ndarray]]:
    """Each link's frame in the world (name, rotation, origin), the root's given, the
    joints at ``joints`` (a fixed joint's, and any not named, at 0)."""
    children: dict[str, list[UrdfJoint]] = {}
    for joint in model.joints:
        children.setdefault(joint.parent, []).append(joint)
    stack = [(model.root, rotation, position)]
    while stack:
        name, turn, at = stack.pop()
        yield name, turn, at
        for joint in children.get(name, []):
            child_turn = turn @ rpy_rotation(joint.origin.rpy)
            child_at = at + turn @ np.array(joint.origin.xyz)
            value = joints.get(joint.name, 0.0)
            if joint.kind in ("revolute", "continuous"):
                child_turn = child_turn @ _matrix(_about(joint.axis, value))
            elif joint.kind == "prismatic":
                child_at = child_at + child_turn @ (np.array(joint.axis) * value)
            stack.append((joint.child, child_turn, child_at))


def _lowest_points(
    model: UrdfModel, rotation: np.ndarray, position: np.ndarray, joints: Mapping[str, float]
) -> Iterator[float]:
    """The height of each link's lowest point (of a link with no shape, its origin's)."""
    for name, turn, at in link_frames(model, rotation, position, joints):
        shapes = model.links[name].shapes
        if not shapes:
            yield float(at[2])
        for shape in shapes:
            yield _lowest(shape, turn, at)


def _lowest(shape: Shape, turn: np.ndarray, at: np.ndarray) -> float:
    """A shape's lowest point, its link frame at (``turn``, ``at``) in the world."""
    heights = (turn @ rpy_rotation(shape.origin.rpy))[2]  # the world z of its own axes
    centre = float((at + turn @ np.array(shape.origin.xyz))[2])
    if shape.kind == "box":
        return centre - sum(abs(h) * side / 2 for h, side in zip(heights, shape.size, strict=True))
    if shape.kind == "sphere":
        return centre - shape.size[0]
    radius, length = shape.size
    up = float(heights[2])
    reach = abs(up) * length / 2
    if shape.kind == "capsule":
        return centre - reach - radius
    return centre - reach - radius * math.sqrt(max(0.0, 1.0 - up * up))
