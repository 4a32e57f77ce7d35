"""What :class:`~adworker.tasks.robot.Robot` builds from: links' shapes and joints.

Two sources: a typed Design (its shapes follow ``adclient.design``'s conventions, every
joint revolute, and a free robot is laid on its side), or a URDF of the user's own (a
template study: shapes and joints as the file gives them, each shape placed by its
origin, and a free robot set down as built). Either way a link's shape is points in the
link frame plus two radii: ``radius``, a cylinder's rim about its axis, and ``ball``,
a sphere's or capsule's all round.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from itertools import product

import numpy as np

from adclient.designs import Design
from adclient.spawn import design_model, rpy_rotation
from adclient.urdf_model import DRIVEN_KINDS, Shape, UrdfModel

_Z = np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class LinkShape:
    """A link's shape in its link frame: ``points`` (a cylinder's or capsule's axis
    ends, a box's corners, a sphere's centre), ``radius`` (rim about ``axis``),
    ``ball`` (all round), its ``centre``, ``axis`` (the long one) and ``length``."""

    kind: str
    points: np.ndarray
    centre: np.ndarray
    radius: float
    ball: float
    axis: np.ndarray
    length: float


@dataclass(frozen=True)
class JointModel:
    name: str
    kind: str
    """revolute, continuous, prismatic (driven) or fixed."""
    parent: str
    child: str
    axis: tuple[float, float, float]
    """A design's: in its parent's frame at rest (its offset applied); a URDF's: in its
    joint frame, as the file gives it (only a design is laid down by its first axis)."""
    lower: float
    upper: float
    effort: float
    velocity: float

    @property
    def driven(self) -> bool:
        return self.kind in DRIVEN_KINDS


JOINT_FIELDS = tuple(field.name for field in fields(JointModel))


@dataclass(frozen=True)
class RobotModel:
    root: str
    shapes: dict[str, LinkShape]
    joints: tuple[JointModel, ...]
    masses: dict[str, float] | None
    """Each link's mass as the design gives it; None: as the engine loaded it."""
    lay_down: bool
    """A free robot starts on its side along +x (a design's chain) or as built (a URDF)."""
    kinematics: UrdfModel
    """The links' shapes and the joints' frames as its URDF gives them: what its spawn
    pose is computed from (``adclient.spawn``)."""


def design_link_shape(shape: str, length: float, radius: float) -> LinkShape:
    """A design link's shape (``adclient.design``: z in [0, length]; a box 2 radius
    wide; a capsule's balls reach radius past each end)."""
    centre = np.array([0.0, 0.0, length / 2])
    if shape == "box":
        signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
        half = np.array([radius, radius, length / 2])
        return LinkShape("box", centre + signs * half, centre, 0.0, 0.0, _Z, length)
    ends = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, length]])
    if shape == "capsule":
        return LinkShape("capsule", ends, centre, 0.0, radius, _Z, length)
    return LinkShape("cylinder", ends, centre, radius, 0.0, _Z, length)


def model_of_design(design: Design) -> RobotModel:
    """A design's robot: its joints of their kinds, a free one laid on its side."""
    return RobotModel(
        root=design.root,
        shapes={
            link.name: design_link_shape(link.shape, link.length, link.radius)
            for link in design.links
        },
        joints=tuple(
            JointModel(
                name=joint.name,
                kind=joint.kind,
                parent=joint.parent,
                child=joint.child,
                axis=_turned(joint.offset, joint.axis),
                lower=joint.limits[0],
                upper=joint.limits[1],
                effort=joint.effort,
                velocity=joint.velocity,
            )
            for joint in design.joints
        ),
        masses={link.name: link.mass for link in design.links},
        lay_down=True,
        kinematics=design_model(design),
    )


def model_of_urdf(model: UrdfModel) -> RobotModel:
    return RobotModel(
        root=model.root,
        shapes={name: _urdf_link_shape(link.shapes) for name, link in model.links.items()},
        joints=tuple(
            JointModel(**{key: getattr(joint, key) for key in JOINT_FIELDS})
            for joint in model.joints
        ),
        masses=None,
        lay_down=False,
        kinematics=model,
    )


def _turned(
    rpy: tuple[float, float, float], axis: tuple[float, float, float]
) -> tuple[float, float, float]:
    if not any(rpy):
        return axis
    x, y, z = rpy_rotation(rpy) @ np.array(axis)
    return (float(x), float(y), float(z))


def _one_shape(shape: Shape) -> LinkShape:
    rotation = rpy_rotation(shape.origin.rpy)
    centre = np.array(shape.origin.xyz)
    if shape.kind == "sphere":
        (radius,) = shape.size
        return LinkShape("sphere", centre[None, :], centre, 0.0, radius, _Z, 2 * radius)
    if shape.kind == "box":
        half = np.array(shape.size) / 2
        corners = np.array(list(product((-1, 1), repeat=3))) * half
        longest = rotation[:, int(np.argmax(shape.size))]
        return LinkShape(
            "box", centre + corners @ rotation.T, centre, 0.0, 0.0, longest, max(shape.size)
        )
    radius, length = shape.size
    axis = rotation[:, 2]
    ends = np.array([centre - axis * length / 2, centre + axis * length / 2])
    if shape.kind == "capsule":
        return LinkShape("capsule", ends, centre, 0.0, radius, axis, length + 2 * radius)
    return LinkShape("cylinder", ends, centre, radius, 0.0, axis, length)


def _bounding_corners(shape: LinkShape) -> np.ndarray:
    """Points whose hull holds the shape: a box's corners, the corners of a box round a
    cylinder's axis, of a cube round each end of a capsule or a sphere."""
    if shape.kind == "box":
        return shape.points
    if shape.kind == "cylinder":
        u = np.cross(shape.axis, [1.0, 0.0, 0.0] if abs(shape.axis[0]) < 0.9 else [0.0, 1.0, 0.0])
        u /= np.linalg.norm(u)
        v = np.cross(shape.axis, u)
        return np.array(
            [
                end + shape.radius * (a * u + b * v)
                for end in shape.points
                for a, b in product((-1, 1), repeat=2)
            ]
        )
    cube = np.array(list(product((-1, 1), repeat=3))) * shape.ball
    return np.array([point + corner for point in shape.points for corner in cube])


def _urdf_link_shape(shapes: tuple[Shape, ...]) -> LinkShape:
    """One primitive exactly; several as the corners of boxes round each (a link's
    highest and lowest points then err by at most a round shape's radius)."""
    if not shapes:  # a frame with no body: a point at its origin
        origin = np.zeros(3)
        return LinkShape("none", origin[None, :], origin, 0.0, 0.0, _Z, 0.0)
    if len(shapes) == 1:
        return _one_shape(shapes[0])
    points = np.concatenate([_bounding_corners(_one_shape(shape)) for shape in shapes])
    low, high = points.min(axis=0), points.max(axis=0)
    return LinkShape("compound", points, (low + high) / 2, 0.0, 0.0, _Z, float(np.max(high - low)))
