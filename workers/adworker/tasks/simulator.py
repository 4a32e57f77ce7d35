"""The PyBullet simulator: one DIRECT client, its ground, its clock and its camera (the
default engine of :mod:`adworker.tasks.engine`).

Every env owns one :class:`Simulator` (no global PyBullet state; ``close()``
disconnects it), so envs in one process never share a world. The robot and the task
read the world through it; only the simulator connects, steps, saves and restores.

PyBullet answers with plain tuples; the positions a caller reads are named here
(:class:`JointInfo`, :class:`DynamicsInfo`, and index constants for the answers read
on every control step, where building a named tuple would cost more than the read).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np
import pybullet

from adworker.tasks.engine import CONTACT_SLACK, GROUND_FRICTION, Camera, EngineSimulator
from adworker.tasks.snapshot import POSE_ORIENTATION, POSE_POSITION

__all__ = [
    "BODY_BASE_NAME",
    "CAMERA_RGBA",
    "CONTACT_DISTANCE",
    "CONTACT_LINK_A",
    "CONTACT_SLACK",
    "GROUND_FRICTION",
    "JOINT_STATE_MOTOR_TORQUE",
    "JOINT_STATE_POSITION",
    "JOINT_STATE_VELOCITY",
    "POSE_ORIENTATION",
    "POSE_POSITION",
    "Camera",
    "DynamicsInfo",
    "JointInfo",
    "Simulator",
]

# Positions in the tuples PyBullet returns on every control step (also POSE_POSITION and
# POSE_ORIENTATION: getBasePositionAndOrientation's and getLinkState(s)'s answers, the
# inertial frame's world pose).
JOINT_STATE_POSITION = 0
JOINT_STATE_VELOCITY = 1
JOINT_STATE_MOTOR_TORQUE = 3
"""getJointState(s): the torque the joint's motor applied during the last physics step
(position and velocity control: the solver's motor impulse over the step)."""
CONTACT_LINK_A = 3
"""getContactPoints(bodyA, bodyB): the link of bodyA in contact (-1: the base)."""
CONTACT_DISTANCE = 8
"""... and the contact distance (negative: penetration)."""
CAMERA_RGBA = 2
"""getCameraImage: the RGBA pixels, row by row."""
BODY_BASE_NAME = 0
"""getBodyInfo: the base link's name (bytes)."""


class JointInfo(NamedTuple):
    """getJointInfo's answer, by name."""

    joint_index: int
    name: bytes
    type: int
    q_index: int
    u_index: int
    flags: int
    damping: float
    friction: float
    lower: float
    upper: float
    max_force: float
    max_velocity: float
    link_name: bytes
    axis: tuple[float, float, float]
    parent_frame_position: tuple[float, float, float]
    parent_frame_orientation: tuple[float, float, float, float]
    parent_index: int


class DynamicsInfo(NamedTuple):
    """getDynamicsInfo's answer, by name."""

    mass: float
    lateral_friction: float
    inertia_diagonal: tuple[float, float, float]
    inertial_position: tuple[float, float, float]
    inertial_orientation: tuple[float, float, float, float]
    restitution: float
    rolling_friction: float
    spinning_friction: float
    contact_damping: float
    contact_stiffness: float
    body_type: int
    collision_margin: float


class Simulator(EngineSimulator):
    """A PyBullet DIRECT client with gravity, a ground plane and a fixed control period.

    One control step is ``frame_skip`` physics steps of ``time_step`` seconds.
    """

    def __init__(self, *, time_step: float, frame_skip: int) -> None:
        super().__init__(time_step=time_step, frame_skip=frame_skip)
        self.before_step: Callable[[], None] | None = None
        """Called before every physics step (torque control: PyBullet applies a joint's
        torque for one step only)."""
        self.client = pybullet.connect(pybullet.DIRECT)
        try:
            self.ground = self._build_world()
        except BaseException:
            self.close()
            raise

    def _build_world(self) -> int:
        cid = self.client
        pybullet.resetSimulation(physicsClientId=cid)
        pybullet.setGravity(0, 0, -9.81, physicsClientId=cid)
        pybullet.setPhysicsEngineParameter(
            fixedTimeStep=self.time_step, deterministicOverlappingPairs=1, physicsClientId=cid
        )
        shape = pybullet.createCollisionShape(pybullet.GEOM_PLANE, physicsClientId=cid)
        visual = pybullet.createVisualShape(
            pybullet.GEOM_BOX,
            halfExtents=[5, 5, 0.001],
            visualFramePosition=[0, 0, -0.001],
            rgbaColor=[0.85, 0.85, 0.82, 1],
            physicsClientId=cid,
        )
        ground = pybullet.createMultiBody(0, shape, visual, physicsClientId=cid)
        pybullet.changeDynamics(ground, -1, lateralFriction=GROUND_FRICTION, physicsClientId=cid)
        return int(ground)

    def load_urdf(self, path: str, *, fixed_base: bool) -> int:
        """A body from a URDF file, its inertias as written and its cylinders exact."""
        return int(
            pybullet.loadURDF(
                path,
                useFixedBase=fixed_base,
                flags=pybullet.URDF_USE_INERTIA_FROM_FILE | pybullet.URDF_USE_IMPLICIT_CYLINDER,
                physicsClientId=self.client,
            )
        )

    def joint_info(self, body: int, joint: int) -> JointInfo:
        return JointInfo(*pybullet.getJointInfo(body, joint, physicsClientId=self.client))

    def dynamics_info(self, body: int, link: int) -> DynamicsInfo:
        return DynamicsInfo(*pybullet.getDynamicsInfo(body, link, physicsClientId=self.client))

    def step(self, each: Callable[[], None] | None = None) -> None:
        """One control step: ``frame_skip`` physics steps, ``each`` called after every
        one (a meter that reads what happened during that physics step)."""
        cid = self.client
        before = self.before_step
        if before is not None:
            for _ in range(self.frame_skip):
                before()
                pybullet.stepSimulation(physicsClientId=cid)
                if each is not None:
                    each()
        elif each is None:
            for _ in range(self.frame_skip):
                pybullet.stepSimulation(physicsClientId=cid)
        else:
            for _ in range(self.frame_skip):
                pybullet.stepSimulation(physicsClientId=cid)
                each()
        self.physics_steps += self.frame_skip

    def save_state(self) -> int:
        return int(pybullet.saveState(physicsClientId=self.client))

    def restore_state(self, state: int, body: int, *others: int) -> None:
        """Restore a saved state with no contact cached from before.

        Bullet keeps contact manifolds across restoreState: points cached from the last
        episode would seed the next one's contacts. Lifting ``body`` (and ``others``, a
        payload) clear and running collision detection once drops them, so every
        episode starts alike.
        """
        cid = self.client
        pybullet.resetBasePositionAndOrientation(body, [0, 0, 100.0], [0, 0, 0, 1], cid)
        for k, other in enumerate(others, start=2):  # apart from it and from each other
            pybullet.resetBasePositionAndOrientation(other, [0, 0, 100.0 * k], [0, 0, 0, 1], cid)
        pybullet.performCollisionDetection(physicsClientId=cid)
        pybullet.restoreState(state, physicsClientId=cid)

    def ground_contacts(self, body: int) -> list[Any]:
        """The engine's contact points between ``body`` and the ground (raw tuples)."""
        return list(pybullet.getContactPoints(body, self.ground, physicsClientId=self.client))

    def camera(
        self, target: np.ndarray, distance: float, width: int = 320, height: int = 240
    ) -> Camera:
        """A camera at a fixed angle, ``distance`` from ``target``, making pictures of
        ``width`` x ``height`` pixels."""
        cid = self.client
        view = pybullet.computeViewMatrixFromYawPitchRoll(
            cameraTargetPosition=[float(value) for value in target],
            distance=distance,
            yaw=35.0,
            pitch=-25.0,
            roll=0.0,
            upAxisIndex=2,
            physicsClientId=cid,
        )
        projection = pybullet.computeProjectionMatrixFOV(
            fov=50.0, aspect=width / height, nearVal=0.02, farVal=20.0, physicsClientId=cid
        )
        return Camera(tuple(view), tuple(projection), width, height)

    def render(self, camera: Camera) -> np.ndarray:
        """The world as ``camera`` sees it: an RGB array, through PyBullet's software
        renderer (works headless)."""
        image = pybullet.getCameraImage(
            camera.width,
            camera.height,
            viewMatrix=list(camera.view),
            projectionMatrix=list(camera.projection),
            renderer=pybullet.ER_TINY_RENDERER,
            lightDirection=[1.0, 1.0, 2.0],
            shadow=1,
            physicsClientId=self.client,
        )
        shape = (camera.height, camera.width, 4)
        rgba = np.reshape(np.asarray(image[CAMERA_RGBA], dtype=np.uint8), shape)
        return rgba[:, :, :3].copy()

    @property
    def connected(self) -> bool:
        return self.client >= 0

    def close(self) -> None:
        if self.client >= 0:
            with contextlib.suppress(pybullet.error):
                pybullet.disconnect(physicsClientId=self.client)
            self.client = -1
