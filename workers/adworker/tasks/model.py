"""What :class:`~adworker.tasks.robot.Robot` builds from: links' shapes and joints.

Two sources: a typed Design (its shapes follow ``adclient.design``'s conventions, every
joint revolute, and a free robot is laid on its side), or a URDF of the user's own (a
template study: shapes and joints as the file gives them, each shape placed by its
origin, and a free robot set down as built). Either way a link's shape is points in the
link frame plus two radii: ``radius``, a cylinder's rim about its axis, and ``ball``,
a sphere's or capsule's all round.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from itertools import product

import numpy as np

from adclient.designs import Design, Joint
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


@dataclass(frozen=True)
class RobotModel:
    root: str
    shapes: dict[str, LinkShape]
    joints: tuple[JointModel, ...]
    masses: dict[str, float] | None
    """Each link's mass as the design gives it; None: as the engine loaded it."""
    lay_down: bool
    """A free robot starts on its side along +x (a design's chain) or as built (a URDF)."""


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
                # an empty range (lower = upper) leaves a revolute joint free all round
                lower=-math.pi if _all_round(joint) else joint.lower,
                upper=math.pi if _all_round(joint) else joint.upper,
                effort=joint.effort,
                velocity=joint.velocity,
            )
            for joint in design.joints
        ),
        masses={link.name: link.mass for link in design.links},
        lay_down=True,
    )


def _all_round(joint: Joint) -> bool:
    return joint.kind in ("revolute", "continuous") and not joint.lower < joint.upper


def model_of_urdf(model: UrdfModel) -> RobotModel:
    return RobotModel(
        root=model.root,
        shapes={name: _urdf_link_shape(link.shapes) for name, link in model.links.items()},
        joints=tuple(JointModel(**asdict(joint)) for joint in model.joints),  # alike
        masses=None,
        lay_down=False,
    )


def _turned(
    rpy: tuple[float, float, float], axis: tuple[float, float, float]
) -> tuple[float, float, float]:
    if not any(rpy):
        return axis
    x, y, z = _rotation(rpy) @ np.array(axis)
    return (float(x), float(y), float(z))


def _rotation(rpy: tuple[float, float, float]) -> np.ndarray:
    """URDF's rpy: fixed-axis roll about x, then pitch about y, then yaw about z."""
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


def _one_shape(shape: Shape) -> LinkShape:
    rotation = _rotation(shape.origin.rpy)
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
