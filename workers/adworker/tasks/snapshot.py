"""What a robot's state looks like after a control step: link poses and shapes as floats.

A :class:`Snapshot` is read once per control step (see ``Robot.read``); tasks turn it
into their metric, reward and observation extras. Per-link values follow the robot's
link order: the root first, then the links by engine index.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

# Positions in a pose, as every engine's snapshot holds it (PyBullet's own answers).
POSE_POSITION = 0
"""A pose's world position (of the link's centre of mass)."""
POSE_ORIENTATION = 1
"""... and its world orientation, a quaternion (x, y, z, w)."""


@dataclass
class LinkGeometry:
    """One link's collision shape, as points in the link's *pose frame* (see
    ``Snapshot.poses``: PyBullet's inertial frame).

    A cylinder is its axis segment ``p0 -> p1`` plus ``radius`` (its rim about
    ``axis``); a box is its eight corners (``radius`` 0); a sphere or capsule is its
    centre or axis segment plus ``ball`` (all round). ``centre`` is the shape's centre.
    """

    name: str
    index: int
    """The engine's link index (PyBullet's: -1 for the base; MuJoCo's: the body id)."""
    kind: str
    centre: np.ndarray
    points: np.ndarray
    radius: float
    length: float
    mass: float
    axis: np.ndarray
    """The link's long axis in the pose frame: a design link's frame +z, a URDF
    cylinder's or capsule's own axis, a box's longest side."""
    ball: float = 0.0

    @property
    def axis_tuple(self) -> tuple[float, float, float]:
        return (float(self.axis[0]), float(self.axis[1]), float(self.axis[2]))

    def constants(self) -> tuple[Any, ...]:
        """The shape as plain floats: a snapshot's float math reads these."""
        return (
            *(float(v) for v in self.centre),
            *(float(v) for v in self.axis),
            [tuple(float(v) for v in point) for point in self.points],
            self.radius,
            self.ball,
        )


class Snapshot:
    """The state read once after each control step, as plain floats.

    Everything past the engine's raw answers (heights, extents, axes) is computed when
    first asked for, so a control step pays only for what its task and observation use.
    """

    def __init__(
        self,
        q: list[float],
        qd: list[float],
        poses: list[Any],
        touching: list[bool],
        geometry: list[LinkGeometry],
        constants: list[tuple[Any, ...]],
    ) -> None:
        self.q = q
        self.qd = qd
        self.poses = poses
        """Per link, the engine's pose answer: ``POSE_POSITION`` and ``POSE_ORIENTATION``
        (xyzw) of the link's *pose frame*, in world: a frame at its centre of mass, in
        which its ``geometry`` is given (PyBullet's: the inertial frame; MuJoCo's: the
        link frame's axes moved to the centre of mass)."""
        self.touching = touching
        """The engine reports a contact between the link and the ground."""
        self.geometry = geometry
        self._constants = constants
        self._axes: dict[int, tuple[float, float, float]] = {}

    def position(self, k: int) -> tuple[float, float, float]:
        """World position of link k's centre of mass (its pose frame's origin)."""
        return self.poses[k][POSE_POSITION]

    def orientation(self, k: int) -> tuple[float, float, float, float]:
        """World orientation (xyzw) of link k's pose frame."""
        return self.poses[k][POSE_ORIENTATION]

    @functools.cached_property
    def _rows(self) -> list[tuple[float, float, float, float]]:
        rows = []
        for pose in self.poses:
            x, y, z, w = pose[POSE_ORIENTATION]
            # Third row of the rotation matrix: the world height of a local vector.
            rows.append(
                (
                    pose[POSE_POSITION][2],
                    2.0 * (x * z - y * w),
                    2.0 * (y * z + x * w),
                    1.0 - 2.0 * (x * x + y * y),
                )
            )
        return rows

    @functools.cached_property
    def centre_z(self) -> list[float]:
        """Height of each link's shape centre."""
        return [
            pz + r0 * c[0] + r1 * c[1] + r2 * c[2]
            for (pz, r0, r1, r2), c in zip(self._rows, self._constants, strict=True)
        ]

    @functools.cached_property
    def axis_z(self) -> list[float]:
        """Vertical component of each link's long axis (its frame's +z)."""
        return [
            r0 * c[3] + r1 * c[4] + r2 * c[5]
            for (_, r0, r1, r2), c in zip(self._rows, self._constants, strict=True)
        ]

    @functools.cached_property
    def _extent(self) -> tuple[list[float], list[float]]:
        top = []
        bottom = []
        for (pz, r0, r1, r2), c, up in zip(self._rows, self._constants, self.axis_z, strict=True):
            heights = [pz + r0 * px + r1 * py + r2 * pz_ for px, py, pz_ in c[6]]
            # A cylinder's rim reaches radius * sin(tilt) above/below its end centres.
            # A sphere's or capsule's ball reaches its radius every way.
            rim = c[7] * math.sqrt(max(0.0, 1.0 - up * up)) + c[8]
            top.append(max(heights) + rim)
            bottom.append(min(heights) - rim)
        return top, bottom

    @property
    def top(self) -> list[float]:
        """Height of each link's highest point."""
        return self._extent[0]

    @property
    def bottom(self) -> list[float]:
        """Height of each link's lowest point."""
        return self._extent[1]

    def rotation(self, k: int) -> np.ndarray:
        return quaternion_matrix(self.orientation(k))

    def centre(self, k: int) -> np.ndarray:
        """World position of link k's shape centre."""
        return np.asarray(self.position(k)) + self.rotation(k) @ self.geometry[k].centre

    def axis(self, k: int) -> tuple[float, float, float]:
        """World direction of link k's long axis (its frame's +z, parent end to tip)."""
        cached = self._axes.get(k)
        if cached is None:
            cached = self._axes[k] = self._axis(k)
        return cached

    def _axis(self, k: int) -> tuple[float, float, float]:
        x, y, z, w = self.orientation(k)
        ax, ay, az = self.geometry[k].axis_tuple
        xx, yy, zz = x * x, y * y, z * z
        xy, xz, yz, wx, wy, wz = x * y, x * z, y * z, w * x, w * y, w * z
        return (
            (1.0 - 2.0 * (yy + zz)) * ax + 2.0 * (xy - wz) * ay + 2.0 * (xz + wy) * az,
            2.0 * (xy + wz) * ax + (1.0 - 2.0 * (xx + zz)) * ay + 2.0 * (yz - wx) * az,
            2.0 * (xz - wy) * ax + 2.0 * (yz + wx) * ay + (1.0 - 2.0 * (xx + yy)) * az,
        )


def quaternion_matrix(quaternion: tuple[float, float, float, float]) -> np.ndarray:
    """The rotation matrix of a unit quaternion (x, y, z, w)."""
    x, y, z, w = quaternion
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz, wx, wy, wz = x * y, x * z, y * z, w * x, w * y, w * z
    return np.array(
        [
            [1.0 - 2.0 * (yy + zz), 2.0 * (xy - wz), 2.0 * (xz + wy)],
            [2.0 * (xy + wz), 1.0 - 2.0 * (xx + zz), 2.0 * (yz - wx)],
            [2.0 * (xz - wy), 2.0 * (yz + wx), 1.0 - 2.0 * (xx + yy)],
        ]
    )
