"""The shared machinery of every task: a URDF robot in its own PyBullet DIRECT client.

A task environment is a Gymnasium env built from a URDF path and a TaskConfig-like
options dict. It owns one PyBullet physics client (no global state; ``close()``
disconnects it), loads a ground plane and the robot, and drives every revolute joint
by position control: the action, in [-1, 1] per joint, is mapped linearly onto the
joint's [lower, upper] range as its target.

Each control step runs ``frame_skip`` physics steps, then reads the state once
(joint states, link poses, contacts) into a :class:`Snapshot`. A subclass turns the
snapshot into its task *metric* (the quantity the score averages) and its reward.
The *score* of an episode is the mean metric over its second half, so a design is
judged on the pose it holds, not on the transient that gets it there.

Evaluation episodes are deterministic for a given seed: ``reset`` restores a state
saved at build time (positions, velocities and contact caches) before applying the
seeded initial perturbation, so an episode's outcome depends only on the seed and
the policy, never on what ran before it.
"""

from __future__ import annotations

import contextlib
import functools
import math
import xml.etree.ElementTree as ElementTree
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
import pybullet

DEFAULT_TIME_STEP = 1.0 / 120.0
DEFAULT_FRAME_SKIP = 12
DEFAULT_EPISODE_STEPS = 32
DEFAULT_INIT_NOISE = 0.05
GROUND_FRICTION = 1.0
ROLLING_FRICTION = 0.02
"""Rolling resistance (m) of the links on the ground. A rubber-coated link touches the
ground over a patch, not at a point, and the patch resists tipping about the contact.
Without it an arch standing on two rim contacts holds only when exactly planar (axes
exactly perpendicular to the chain); with it the score falls off gradually as the
axes tilt away, which is both closer to a real robot and a landscape an optimiser can
climb."""
SPINNING_FRICTION = 0.0
CONTACT_SLACK = 0.002
"""A link touches the ground when the engine reports a contact closer than this (m)."""


@dataclass
class LinkGeometry:
    """One link's collision shape, as points in the link's *inertial* frame.

    A cylinder is its axis segment ``p0 -> p1`` plus ``radius``; a box is its eight
    corners (``radius`` 0). ``centre`` is the shape's centre.
    """

    name: str
    index: int
    kind: str
    centre: np.ndarray
    points: np.ndarray
    radius: float
    length: float
    axis: np.ndarray
    """The link frame's +z (the long axis) in the inertial frame."""

    @property
    def axis_tuple(self) -> tuple[float, float, float]:
        return (float(self.axis[0]), float(self.axis[1]), float(self.axis[2]))


@dataclass
class JointSpec:
    index: int
    name: str
    child: str
    lower: float
    upper: float
    effort: float
    velocity: float


class Snapshot:
    """The state read once after each control step, as plain floats.

    Per-link lists follow ``RobotEnv.geometry`` (the root first). Everything past the
    engine's raw answers (heights, extents, axes) is computed when first asked for, so
    a control step pays only for what its task and observation use.
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
        """(position, xyzw orientation) of each link's inertial frame, in world."""
        self.touching = touching
        """The engine reports a contact between the link and the ground."""
        self.geometry = geometry
        self._constants = constants
        self._axes: dict[int, tuple[float, float, float]] = {}

    @functools.cached_property
    def _rows(self) -> list[tuple[float, float, float, float]]:
        rows = []
        for pose in self.poses:
            x, y, z, w = pose[1]
            # Third row of the rotation matrix: the world height of a local vector.
            rows.append(
                (
                    pose[0][2],
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
            rim = c[7] * math.sqrt(max(0.0, 1.0 - up * up))
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
        return np.reshape(pybullet.getMatrixFromQuaternion(self.poses[k][1]), (3, 3))

    def centre(self, k: int) -> np.ndarray:
        """World position of link k's shape centre."""
        return np.asarray(self.poses[k][0]) + self.rotation(k) @ self.geometry[k].centre

    def axis(self, k: int) -> tuple[float, float, float]:
        """World direction of link k's long axis (its frame's +z, parent end to tip)."""
        cached = self._axes.get(k)
        if cached is None:
            cached = self._axes[k] = self._axis(k)
        return cached

    def _axis(self, k: int) -> tuple[float, float, float]:
        x, y, z, w = self.poses[k][1]
        ax, ay, az = self.geometry[k].axis_tuple
        xx, yy, zz = x * x, y * y, z * z
        xy, xz, yz, wx, wy, wz = x * y, x * z, y * z, w * x, w * y, w * z
        return (
            (1.0 - 2.0 * (yy + zz)) * ax + 2.0 * (xy - wz) * ay + 2.0 * (xz + wy) * az,
            2.0 * (xy + wz) * ax + (1.0 - 2.0 * (xx + zz)) * ay + 2.0 * (yz - wx) * az,
            2.0 * (xz - wy) * ax + 2.0 * (yz + wx) * ay + (1.0 - 2.0 * (xx + yy)) * az,
        )


@dataclass
class EpisodeRecord:
    metric: list[float] = field(default_factory=list)

    def score(self) -> float:
        return episode_score(self.metric)


def episode_score(metric: list[float] | np.ndarray) -> float:
    """Mean of the per-step metric over the second half of an episode."""
    values = np.asarray(metric, dtype=float)
    if values.size == 0:
        return 0.0
    return float(values[values.size // 2 :].mean())


def _rpy_matrix(rpy: tuple[float, ...]) -> np.ndarray:
    roll, pitch, yaw = rpy
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return rz @ ry @ rx


def _floats(text: str | None, count: int, default: float = 0.0) -> tuple[float, ...]:
    if not text:
        return (default,) * count
    values = tuple(float(v) for v in text.split())
    if len(values) != count:
        raise ValueError(f"expected {count} numbers, got {text!r}")
    return values


def read_urdf_shapes(
    urdf_path: Path,
) -> dict[str, tuple[str, np.ndarray, float, float, np.ndarray]]:
    """Per link name: (kind, points in the link frame, radius, length, centre).

    Read from the URDF's first collision element (or visual, if it has none), so the
    task knows each link's extent without trusting where its inertial frame sits.
    """
    root = ElementTree.parse(urdf_path).getroot()
    shapes: dict[str, tuple[str, np.ndarray, float, float, np.ndarray]] = {}
    for link in root.findall("link"):
        name = link.get("name", "")
        element = link.find("collision")
        if element is None:
            element = link.find("visual")
        geometry = element.find("geometry") if element is not None else None
        if element is None or geometry is None:
            shapes[name] = ("point", np.zeros((1, 3)), 0.0, 0.0, np.zeros(3))
            continue
        origin = element.find("origin")
        xyz = np.array(_floats(origin.get("xyz") if origin is not None else None, 3))
        rotation = _rpy_matrix(_floats(origin.get("rpy") if origin is not None else None, 3))
        cylinder = geometry.find("cylinder")
        box = geometry.find("box")
        sphere = geometry.find("sphere")
        if cylinder is not None:
            length = float(cylinder.get("length", "0"))
            radius = float(cylinder.get("radius", "0"))
            half = rotation @ np.array([0.0, 0.0, length / 2])
            shapes[name] = ("cylinder", np.stack([xyz - half, xyz + half]), radius, length, xyz)
        elif box is not None:
            size = np.array(_floats(box.get("size"), 3))
            signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
            corners = xyz + (signs * size / 2) @ rotation.T
            shapes[name] = ("box", corners, 0.0, float(size[2]), xyz)
        elif sphere is not None:
            radius = float(sphere.get("radius", "0"))
            shapes[name] = ("sphere", xyz[None, :], radius, 0.0, xyz)
        else:
            shapes[name] = ("point", xyz[None, :], 0.0, 0.0, xyz)
    return shapes


def _inverse_transform_points(
    points: np.ndarray, position: tuple[float, ...], orientation: tuple[float, ...]
) -> np.ndarray:
    """Points in the link frame -> the link's inertial frame (given the inertial pose)."""
    rotation = np.reshape(pybullet.getMatrixFromQuaternion(orientation), (3, 3))
    return (points - np.asarray(position)) @ rotation


class RobotEnv(gym.Env[np.ndarray, np.ndarray]):
    """A robot from a URDF in its own PyBullet DIRECT client; see the module docstring."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 30}

    task_name: ClassVar[str] = "robot"
    fixed_base: ClassVar[bool] = False
    reads_contacts: ClassVar[bool] = True
    """Whether each step reads ground contacts (observed as one flag per link)."""
    default_episode_steps: ClassVar[int] = DEFAULT_EPISODE_STEPS

    def __init__(
        self,
        urdf_path: str | Path,
        options: dict[str, Any] | None = None,
        render_mode: str | None = None,
    ) -> None:
        super().__init__()
        self.urdf_path = Path(urdf_path)
        self.options = dict(options or {})
        self.render_mode = render_mode
        self.episode_steps = int(self.options.get("episode_steps") or self.default_episode_steps)
        self.frame_skip = int(self.options.get("frame_skip", DEFAULT_FRAME_SKIP))
        self.time_step = float(self.options.get("time_step", DEFAULT_TIME_STEP))
        self.init_noise = float(self.options.get("init_noise", DEFAULT_INIT_NOISE))
        self.rolling_friction = float(self.options.get("rolling_friction", ROLLING_FRICTION))
        self.spinning_friction = float(self.options.get("spinning_friction", SPINNING_FRICTION))
        if self.episode_steps < 2 or self.frame_skip < 1 or self.time_step <= 0:
            raise ValueError("episode_steps >= 2, frame_skip >= 1 and time_step > 0 required")
        self.sim_steps = 0
        self._client = -1
        self._client = pybullet.connect(pybullet.DIRECT)
        try:
            self._build()
        except BaseException:
            self.close()
            raise
        self.record = EpisodeRecord()
        self._step_count = 0
        self._last: Snapshot | None = None

    # ----------------------------------------------------------------- building

    def _build(self) -> None:
        cid = self._client
        pybullet.resetSimulation(physicsClientId=cid)
        pybullet.setGravity(0, 0, -9.81, physicsClientId=cid)
        pybullet.setPhysicsEngineParameter(
            fixedTimeStep=self.time_step, deterministicOverlappingPairs=1, physicsClientId=cid
        )
        ground_shape = pybullet.createCollisionShape(pybullet.GEOM_PLANE, physicsClientId=cid)
        ground_visual = pybullet.createVisualShape(
            pybullet.GEOM_BOX,
            halfExtents=[5, 5, 0.001],
            visualFramePosition=[0, 0, -0.001],
            rgbaColor=[0.85, 0.85, 0.82, 1],
            physicsClientId=cid,
        )
        self.ground = pybullet.createMultiBody(0, ground_shape, ground_visual, physicsClientId=cid)
        pybullet.changeDynamics(
            self.ground, -1, lateralFriction=GROUND_FRICTION, physicsClientId=cid
        )
        shapes = read_urdf_shapes(self.urdf_path)
        self.robot = pybullet.loadURDF(
            str(self.urdf_path),
            useFixedBase=self.fixed_base,
            flags=pybullet.URDF_USE_INERTIA_FROM_FILE | pybullet.URDF_USE_IMPLICIT_CYLINDER,
            physicsClientId=cid,
        )
        root_name = pybullet.getBodyInfo(self.robot, physicsClientId=cid)[0].decode()
        self.joints: list[JointSpec] = []
        link_indices = {root_name: -1}
        for j in range(pybullet.getNumJoints(self.robot, physicsClientId=cid)):
            info = pybullet.getJointInfo(self.robot, j, physicsClientId=cid)
            child = info[12].decode()
            link_indices[child] = j
            if info[2] != pybullet.JOINT_REVOLUTE:
                continue
            lower, upper = float(info[8]), float(info[9])
            if not lower < upper:
                lower, upper = -math.pi, math.pi
            effort = float(info[10]) if info[10] > 0 else 20.0
            velocity = float(info[11]) if info[11] > 0 else 5.0
            self.joints.append(
                JointSpec(j, info[1].decode(), child, lower, upper, effort, velocity)
            )
        if not self.joints:
            raise ValueError(f"{self.urdf_path.name}: the robot has no revolute joint")
        self.link_names = list(link_indices)
        self.link_index = link_indices
        self.root_name = root_name
        self.geometry: list[LinkGeometry] = []
        for name in self.link_names:
            index = link_indices[name]
            kind, points, radius, length, centre = shapes.get(
                name, ("point", np.zeros((1, 3)), 0.0, 0.0, np.zeros(3))
            )
            dynamics = pybullet.getDynamicsInfo(self.robot, index, physicsClientId=cid)
            local_pos, local_orn = dynamics[3], dynamics[4]
            self.geometry.append(
                LinkGeometry(
                    name=name,
                    index=index,
                    kind=kind,
                    centre=_inverse_transform_points(centre[None, :], local_pos, local_orn)[0],
                    points=_inverse_transform_points(points, local_pos, local_orn),
                    radius=radius,
                    length=length,
                    axis=_inverse_transform_points(
                        np.array([[0.0, 0.0, 1.0]]), (0.0, 0.0, 0.0), local_orn
                    )[0],
                )
            )
            pybullet.changeDynamics(
                self.robot,
                index,
                lateralFriction=GROUND_FRICTION,
                rollingFriction=self.rolling_friction,
                spinningFriction=self.spinning_friction,
                physicsClientId=cid,
            )
        for joint in self.joints:
            pybullet.changeDynamics(
                self.robot, joint.index, maxJointVelocity=joint.velocity, physicsClientId=cid
            )
        self._joint_indices = [joint.index for joint in self.joints]
        self._child_indices = [index for index in link_indices.values() if index >= 0]
        self._lower = np.array([joint.lower for joint in self.joints])
        self._upper = np.array([joint.upper for joint in self.joints])
        self._lower_list = [joint.lower for joint in self.joints]
        self._half_span = [(joint.upper - joint.lower) / 2 for joint in self.joints]
        self._mid = [(joint.upper + joint.lower) / 2 for joint in self.joints]
        self._inv_half = [2.0 / (joint.upper - joint.lower) for joint in self.joints]
        self._inv_velocity = [1.0 / joint.velocity for joint in self.joints]
        self._efforts = [joint.effort for joint in self.joints]
        self.joint_count = len(self.joints)
        self._geometry_arrays()
        self._place_robot()
        self._saved_state = pybullet.saveState(physicsClientId=cid)
        n = len(self.joints)
        self.action_space = gym.spaces.Box(-1.0, 1.0, shape=(n,), dtype=np.float32)
        size = self.observation_size()
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, shape=(size,), dtype=np.float32)

    def _geometry_arrays(self) -> None:
        """Per-link constants as plain tuples: a snapshot is a short loop of float math."""
        self._link_constants = [
            (
                *(float(v) for v in g.centre),
                *(float(v) for v in g.axis),
                [tuple(float(v) for v in point) for point in g.points],
                g.radius,
            )
            for g in self.geometry
        ]
        self._link_slot = {g.index: k for k, g in enumerate(self.geometry)}

    def _place_robot(self) -> None:
        """Lay a free robot on its side along world +x, its lowest point just touching.

        The chain at rest (the root frame's +z) runs along world +x. Lying on round
        links, the robot could rest at any roll about that line; it is laid with the
        axis of the root's first joint horizontal, so bending that joint lifts links
        off the ground (as anyone setting the robot down would place it). What the
        design then decides is how the other axes sit relative to that one: parallel
        ones fold the chain in a vertical plane, others twist it out of that plane.
        A fixed-base robot stays where its URDF puts it: root frame at the origin.
        """
        if self.fixed_base:
            return
        cid = self._client
        roll = 0.0
        for j in range(pybullet.getNumJoints(self.robot, physicsClientId=cid)):
            info = pybullet.getJointInfo(self.robot, j, physicsClientId=cid)
            if info[16] == -1 and info[2] == pybullet.JOINT_REVOLUTE:
                ux, uy, _ = info[13]
                if math.hypot(ux, uy) > 1e-6:
                    # Root +x, +y, +z land on world -z, +y, +x; rolling by atan2(ux, uy)
                    # about world x brings the axis into the horizontal plane.
                    roll = math.atan2(ux, uy)
                break
        _, orientation = pybullet.multiplyTransforms(
            [0, 0, 0],
            pybullet.getQuaternionFromEuler([roll, 0.0, 0.0]),
            [0, 0, 0],
            pybullet.getQuaternionFromEuler([0.0, math.pi / 2, 0.0]),
        )
        pybullet.resetBasePositionAndOrientation(self.robot, [0, 0, 1.0], orientation, cid)
        for joint in self.joints:
            pybullet.resetJointState(self.robot, joint.index, 0.0, 0.0, cid)
        bottom = min(self._read().bottom)
        height = 1.0 - bottom + 1e-4
        pybullet.resetBasePositionAndOrientation(self.robot, [0, 0, height], orientation, cid)

    # ---------------------------------------------------------------- stepping

    def observation_size(self) -> int:
        """Joint positions and velocities; for a free base its tilt, height and the links'
        heights; one ground-contact flag per link where contacts are read; task extras."""
        size = 2 * len(self.joints) + self.task_observation_size()
        if not self.fixed_base:
            size += 4 + len(self.geometry)
        if self.reads_contacts:
            size += len(self.geometry)
        return size

    def task_observation_size(self) -> int:
        return 0

    def task_observation(self, snapshot: Snapshot) -> list[float]:
        return []

    def metric(self, snapshot: Snapshot) -> float:
        """The per-step quantity whose second-half mean is the episode score."""
        raise NotImplementedError

    def reward(self, snapshot: Snapshot, metric: float) -> float:
        return metric

    def targets(self, action: np.ndarray) -> list[float]:
        """Joint position targets: the action in [-1, 1] mapped onto [lower, upper]."""
        values = action.tolist() if isinstance(action, np.ndarray) else list(action)
        if len(values) != len(self._mid):
            raise ValueError(f"expected {len(self._mid)} joint targets, got {len(values)}")
        return [
            mid + (1.0 if a > 1.0 else -1.0 if a < -1.0 else a) * half
            for a, mid, half in zip(values, self._mid, self._half_span, strict=True)
        ]

    def _read(self) -> Snapshot:
        """One read of the state after a control step: a few engine calls, float math.

        Kept to plain Python floats on purpose: with three to five links, numpy's
        per-call cost would exceed the arithmetic (see bench/evaluation.py, overhead).
        """
        cid = self._client
        robot = self.robot
        states = pybullet.getJointStates(robot, self._joint_indices, physicsClientId=cid)
        poses = [pybullet.getBasePositionAndOrientation(robot, physicsClientId=cid)]
        if self._child_indices:
            poses += pybullet.getLinkStates(
                robot, self._child_indices, computeForwardKinematics=1, physicsClientId=cid
            )
        touching = [False] * len(poses)
        if self.reads_contacts:
            slot = self._link_slot
            for contact in pybullet.getContactPoints(robot, self.ground, physicsClientId=cid):
                if contact[8] <= CONTACT_SLACK:
                    touching[slot[contact[3]]] = True
        return Snapshot(
            [s[0] for s in states],
            [s[1] for s in states],
            poses,
            touching,
            self.geometry,
            self._link_constants,
        )

    def _observe(self, snapshot: Snapshot) -> np.ndarray:
        values = [
            (q - mid) * inv
            for q, mid, inv in zip(snapshot.q, self._mid, self._inv_half, strict=True)
        ]
        values += [qd * inv for qd, inv in zip(snapshot.qd, self._inv_velocity, strict=True)]
        if not self.fixed_base:
            # A fixed base never moves: its pose and its links' heights (functions of the
            # joint angles) would add nothing.
            x, y, z, w = snapshot.poses[0][1]
            # World +z seen from the root frame: the body's tilt.
            values += (2.0 * (x * z - y * w), 2.0 * (y * z + x * w), 1.0 - 2.0 * (x * x + y * y))
            values.append(snapshot.poses[0][0][2])
            values += snapshot.centre_z
        if self.reads_contacts:
            values += snapshot.touching
        values += self.task_observation(snapshot)
        return np.array(values, dtype=np.float32)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        cid = self._client
        # Bullet keeps contact manifolds across restoreState: points cached from the
        # last episode would seed the next one's contacts. Lift the robot clear and run
        # collision detection once, which drops them, so every episode starts alike.
        pybullet.resetBasePositionAndOrientation(self.robot, [0, 0, 100.0], [0, 0, 0, 1], cid)
        pybullet.performCollisionDetection(physicsClientId=cid)
        pybullet.restoreState(self._saved_state, physicsClientId=cid)
        noise = self.np_random.uniform(-self.init_noise, self.init_noise, len(self.joints))
        start = np.clip(noise, self._lower, self._upper)
        for joint, angle in zip(self.joints, start, strict=True):
            pybullet.resetJointState(self.robot, joint.index, float(angle), 0.0, cid)
        pybullet.setJointMotorControlArray(
            self.robot,
            self._joint_indices,
            pybullet.POSITION_CONTROL,
            targetPositions=start.tolist(),
            forces=self._efforts,
            physicsClientId=cid,
        )
        self.record = EpisodeRecord()
        self._step_count = 0
        snapshot = self._read()
        self._last = snapshot
        return self._observe(snapshot), {}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        cid = self._client
        targets = self.targets(action)
        pybullet.setJointMotorControlArray(
            self.robot,
            self._joint_indices,
            pybullet.POSITION_CONTROL,
            targetPositions=targets,
            forces=self._efforts,
            physicsClientId=cid,
        )
        for _ in range(self.frame_skip):
            pybullet.stepSimulation(physicsClientId=cid)
        self.sim_steps += self.frame_skip
        snapshot = self._read()
        self._last = snapshot
        metric = self.metric(snapshot)
        self.record.metric.append(metric)
        self._step_count += 1
        truncated = self._step_count >= self.episode_steps
        info: dict[str, Any] = {"score": self.record.score()} if truncated else {}
        return self._observe(snapshot), float(self.reward(snapshot, metric)), False, truncated, info

    # ------------------------------------------------------------ inspection

    def snapshot(self) -> Snapshot:
        if self._last is None:
            self._last = self._read()
        return self._last

    def link_position(self, name: str) -> int:
        """Position of a link (by instance name) in the snapshot arrays."""
        for k, g in enumerate(self.geometry):
            if g.name == name:
                return k
        raise KeyError(f"{self.task_name}: the robot has no link named {name!r}")

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        return self.render_image()

    def render_image(self, width: int = 320, height: int = 240) -> np.ndarray:
        """The current pose through PyBullet's software renderer (works headless)."""
        cid = self._client
        snapshot = self.snapshot()
        centres = np.array([snapshot.centre(k) for k in range(len(self.geometry))])
        target = centres.mean(axis=0)
        extent = float(np.ptp(centres, axis=0).max()) + max(
            (g.length for g in self.geometry), default=0.4
        )
        view = pybullet.computeViewMatrixFromYawPitchRoll(
            cameraTargetPosition=target.tolist(),
            distance=max(1.0, 1.6 * extent),
            yaw=35.0,
            pitch=-25.0,
            roll=0.0,
            upAxisIndex=2,
            physicsClientId=cid,
        )
        projection = pybullet.computeProjectionMatrixFOV(
            fov=50.0, aspect=width / height, nearVal=0.02, farVal=20.0, physicsClientId=cid
        )
        image = pybullet.getCameraImage(
            width,
            height,
            viewMatrix=view,
            projectionMatrix=projection,
            renderer=pybullet.ER_TINY_RENDERER,
            lightDirection=[1.0, 1.0, 2.0],
            shadow=1,
            physicsClientId=cid,
        )
        rgba = np.reshape(np.asarray(image[2], dtype=np.uint8), (height, width, 4))
        return rgba[:, :, :3].copy()

    def close(self) -> None:
        if self._client >= 0:
            with contextlib.suppress(pybullet.error):
                pybullet.disconnect(physicsClientId=self._client)
            self._client = -1
        super().close()
