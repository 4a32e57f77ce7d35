"""The robot: a typed Design, or a URDF of the user's own, put into a simulator and
driven by joint position targets.

Links, shapes, joints and limits come from a :class:`~adworker.tasks.model.RobotModel`:
a design's (the geometry conventions of ``adclient.design``; its URDF is only handed to
the engine to build the body) or a template's URDF read by ``adclient.urdf_model``.
What the engine decides is asked of the engine: each link's index and its inertial
frame (the frame it reports poses in), and a URDF's masses. The two are checked
against each other, so a URDF that is not the model's fails at build time instead of
scoring the wrong robot.

Every driven joint (revolute, continuous, prismatic; fixed joints only hold links) is
driven by position control: the action, in [-1, 1] per joint, maps linearly onto the
joint's [lower, upper] range as its target (a continuous joint's: -pi to pi). The engine's motor
then applies whatever torque, up to the joint's effort, brings the joint to its target
(capped at its velocity); a :class:`MotorMeter` reads that applied torque after every
physics step. Under torque control (``control: torque``) the position motors are
disabled and each joint takes the action times its effort as its torque, applied before
every physics step (PyBullet applies a commanded torque for one step only).

A payload (``PayloadSpec``) is a box body of its own, set on its link after the robot
is placed and saved with it, so every episode starts with it resting there.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pybullet

from adclient.spawn import spawn_pose
from adworker.tasks.engine import (
    EngineMeter,
    EngineRobot,
    JointSpec,
    PayloadSpec,
    PayloadState,
    payload_start,
)
from adworker.tasks.model import LinkShape, RobotModel
from adworker.tasks.simulator import (
    BODY_BASE_NAME,
    CONTACT_DISTANCE,
    CONTACT_LINK_A,
    CONTACT_SLACK,
    GROUND_FRICTION,
    JOINT_STATE_MOTOR_TORQUE,
    JOINT_STATE_POSITION,
    JOINT_STATE_VELOCITY,
    Simulator,
)
from adworker.tasks.snapshot import LinkGeometry, Snapshot

__all__ = ["JointSpec", "MotorMeter", "Robot"]


class MotorMeter(EngineMeter):
    """The joint motors' effort and mechanical energy over episodes, read after every
    physics step (``Simulator.step``'s ``each``).

    Joints are position-controlled, so the torque a motor applies is the constraint
    solver's, not a commanded one: PyBullet reports it per joint as the applied motor
    torque of the last physics step (``JOINT_STATE_MOTOR_TORQUE``; it never exceeds the
    joint's effort). With tau_j and qd_j that torque and the joint's velocity after
    physics step k of length dt:

    - effort (N m): mean of |tau_j| over every physics step of every metered episode
      and every joint: the time-averaged absolute torque per joint;
    - energy (J): per episode, sum over steps and joints of |tau_j qd_j| dt (the work
      the motors do, braking counted as spent: a motor does not recover energy),
      averaged over episodes.

    Holding a pose against gravity costs effort but no energy; a robot at rest in its
    target pose, its weight on the ground or along its joints' axes, costs neither.
    """

    def __init__(
        self,
        body: int,
        joint_indices: list[int],
        time_step: float,
        client: int,
        commanded: list[float] | None = None,
    ):
        super().__init__(len(joint_indices), time_step)
        self._body = body
        self._joints = list(joint_indices)
        self._client = client
        self._commanded = commanded
        """Torque control: the torques applied (PyBullet reports none for them)."""

    def sample(self) -> None:
        """Read the torques and velocities of the physics step just taken."""
        states = pybullet.getJointStates(self._body, self._joints, physicsClientId=self._client)
        torque = power = 0.0
        commanded = self._commanded
        for j, state in enumerate(states):
            tau = state[JOINT_STATE_MOTOR_TORQUE] if commanded is None else commanded[j]
            torque += abs(tau)
            power += abs(tau * state[JOINT_STATE_VELOCITY])
        self.torque_sum += torque
        self.episode_energy[-1] += power * self._time_step
        self.samples += 1


def _to_inertial(
    points: np.ndarray, position: tuple[float, ...], orientation: tuple[float, ...]
) -> np.ndarray:
    """Points in the link frame -> the link's inertial frame (given the inertial pose)."""
    rotation = np.reshape(pybullet.getMatrixFromQuaternion(orientation), (3, 3))
    return (points - np.asarray(position)) @ rotation


_ENGINE_KIND = {
    "revolute": pybullet.JOINT_REVOLUTE,
    "continuous": pybullet.JOINT_REVOLUTE,
    "prismatic": pybullet.JOINT_PRISMATIC,
    "fixed": pybullet.JOINT_FIXED,
}


class Robot(EngineRobot):
    """A robot model in a PyBullet Simulator: its joints, link shapes, state reads and
    motor commands."""

    sim: Simulator

    def __init__(
        self,
        sim: Simulator,
        model: RobotModel,
        urdf_path: str | Path,
        *,
        fixed_base: bool,
        reads_contacts: bool,
        rolling_friction: float,
        spinning_friction: float,
        control: str = "position",
        payload: PayloadSpec | None = None,
    ) -> None:
        super().__init__(
            sim, model, fixed_base=fixed_base, reads_contacts=reads_contacts, control=control
        )
        self.body = sim.load_urdf(str(urdf_path), fixed_base=fixed_base)
        engine_index = self._engine_indices(Path(urdf_path).name)
        # The root first, then the engine's order (depth first through the tree).
        order = sorted(engine_index, key=engine_index.__getitem__)
        self.geometry = [self._geometry(name, engine_index[name]) for name in order]
        self.link_names = order
        self.joints = [
            JointSpec.of(joint, engine_index[joint.child])
            for joint in sorted(model.joints, key=lambda joint: engine_index[joint.child])
            if joint.driven
        ]
        if not self.joints:
            raise ValueError(f"{Path(urdf_path).name}: the robot has no joint to drive")
        cid = sim.client
        # Rolling friction: a rubber-coated link touches the ground over a patch, not at
        # a point, and the patch resists tipping about the contact. Without it an arch
        # standing on two rim contacts holds only when exactly planar (axes exactly
        # perpendicular to the chain); with it the score falls off gradually as the axes
        # tilt away: closer to a real robot, and a landscape an optimiser can climb.
        for g in self.geometry:
            pybullet.changeDynamics(
                self.body,
                g.index,
                lateralFriction=GROUND_FRICTION,
                rollingFriction=rolling_friction,
                spinningFriction=spinning_friction,
                physicsClientId=cid,
            )
        for joint in self.joints:
            # A joint's speed limit is its motor's. changeDynamics(maxJointVelocity) would
            # set Bullet's one velocity clamp of the whole body, which holds every
            # coordinate, a free base's six velocities included, to the limit: momentum
            # is not conserved and a fast gait gains energy from nowhere (measured: 20 J
            # in its first 0.1 s). Set once here; the per-step array commands keep it.
            pybullet.setJointMotorControl2(
                self.body,
                joint.index,
                pybullet.POSITION_CONTROL,
                targetPosition=0.0,
                force=joint.effort,
                maxVelocity=joint.velocity,
                physicsClientId=cid,
            )
        self.joint_indices = [joint.index for joint in self.joints]
        self._child_indices = [g.index for g in self.geometry if g.index >= 0]
        self._scale_joints()
        self._torque = [0.0] * len(self.joints)
        """Torque control: this control step's torques, applied before every physics step."""
        if control == "torque":
            # A position motor holds its joint until disabled (a velocity motor of no force).
            pybullet.setJointMotorControlArray(
                self.body,
                self.joint_indices,
                pybullet.VELOCITY_CONTROL,
                forces=[0.0] * len(self.joints),
                physicsClientId=cid,
            )
            sim.before_step = self._apply_torques
        self._nominal = [
            (g.index, d.mass, d.inertia_diagonal)
            for g in self.geometry
            for d in (sim.dynamics_info(self.body, g.index),)
        ]
        self._constants = [g.constants() for g in self.geometry]
        self._link_slot = {g.index: k for k, g in enumerate(self.geometry)}
        self.spawn = spawn_pose(model.kinematics, lay_down=model.lay_down, fixed_base=fixed_base)
        """Where every episode starts, before its noise (``adclient.spawn``)."""
        self._place()
        self.payload = -1 if payload is None else self._add_payload(payload)
        self._saved_state = sim.save_state()

    def _add_payload(self, payload: PayloadSpec) -> int:
        """The payload's body, resting on its link in the placed pose."""
        cid = self.sim.client
        half = [payload.size / 2] * 3
        shape = pybullet.createCollisionShape(
            pybullet.GEOM_BOX, halfExtents=half, physicsClientId=cid
        )
        visual = pybullet.createVisualShape(
            pybullet.GEOM_BOX, halfExtents=half, rgbaColor=[0.9, 0.5, 0.1, 1], physicsClientId=cid
        )
        start = payload_start(self, payload)
        body = pybullet.createMultiBody(payload.mass, shape, visual, start, physicsClientId=cid)
        pybullet.changeDynamics(body, -1, lateralFriction=GROUND_FRICTION, physicsClientId=cid)
        return int(body)

    # ----------------------------------------------------------------- building

    def _engine_indices(self, what: str) -> dict[str, int]:
        """Each model link's engine index (the root: -1), checking that the body the
        engine built is this model's tree."""
        sim, model = self.sim, self.model
        base = pybullet.getBodyInfo(self.body, physicsClientId=sim.client)[BODY_BASE_NAME]
        if base.decode() != model.root:
            raise ValueError(f"{what}: the URDF's root is {base.decode()!r}, not the model's")
        parent_of = {joint.child: (joint.name, joint.parent) for joint in model.joints}
        kind_of = {joint.name: joint.kind for joint in model.joints}
        name_of = {-1: model.root}
        for j in range(pybullet.getNumJoints(self.body, physicsClientId=sim.client)):
            info = sim.joint_info(self.body, j)
            child, name = info.link_name.decode(), info.name.decode()
            if parent_of.get(child) != (name, name_of.get(info.parent_index)):
                raise ValueError(f"{what}: joint {name!r} is not the model's")
            if info.type != _ENGINE_KIND[kind_of[name]]:
                raise ValueError(f"{what}: joint {name!r} is not {kind_of[name]}")
            name_of[j] = child
        if len(name_of) != len(model.shapes):
            raise ValueError(
                f"{what}: the URDF has {len(name_of)} links, the model {len(model.shapes)}"
            )
        return {name: j for j, name in name_of.items()}

    def _geometry(self, name: str, index: int) -> LinkGeometry:
        shape: LinkShape = self.model.shapes[name]
        dynamics = self.sim.dynamics_info(self.body, index)
        frame = (dynamics.inertial_position, dynamics.inertial_orientation)
        masses = self.model.masses
        return LinkGeometry(
            name=name,
            index=index,
            kind=shape.kind,
            centre=_to_inertial(shape.centre[None, :], *frame)[0],
            points=_to_inertial(shape.points, *frame),
            radius=shape.radius,
            length=shape.length,
            mass=masses[name] if masses is not None else dynamics.mass,
            axis=_to_inertial(shape.axis[None, :], (0.0, 0.0, 0.0), frame[1])[0],
            ball=shape.ball,
        )

    def _place(self) -> None:
        """Put the robot where ``adclient.spawn`` says (``self.spawn``): the engine poses
        a base by its inertial frame, so the root frame's pose is turned into that."""
        cid = self.sim.client
        spawn = self.spawn
        if not self.fixed_base:
            dynamics = self.sim.dynamics_info(self.body, -1)
            position, orientation = pybullet.multiplyTransforms(
                spawn.position,
                spawn.orientation,
                dynamics.inertial_position,
                dynamics.inertial_orientation,
            )
            pybullet.resetBasePositionAndOrientation(self.body, position, orientation, cid)
        for joint in self.joints:
            pybullet.resetJointState(self.body, joint.index, spawn.joints[joint.name], 0.0, cid)

    # ---------------------------------------------------------------- stepping

    def reset(self, start: np.ndarray) -> Snapshot:
        """Back to the placed pose with the joints at ``start`` (clipped to their limits),
        holding there."""
        cid = self.sim.client
        if self.payload >= 0:
            self.sim.restore_state(self._saved_state, self.body, self.payload)
        else:
            self.sim.restore_state(self._saved_state, self.body)
        start = np.clip(start, self.lower, self.upper)
        for joint, angle in zip(self.joints, start, strict=True):
            pybullet.resetJointState(self.body, joint.index, float(angle), 0.0, cid)
        if self.control == "torque":
            self._torque[:] = [0.0] * len(self.joints)
        else:
            self._command(start.tolist())
        return self.read()

    def motor_meter(self) -> MotorMeter:
        """A new meter of this robot's motors (see :class:`MotorMeter`)."""
        commanded = self._torque if self.control == "torque" else None
        return MotorMeter(
            self.body, self.joint_indices, self.sim.time_step, self.sim.client, commanded
        )

    def act(self, action: np.ndarray) -> None:
        """Command the joints towards the action's targets, or their torques (takes effect
        as the simulator steps)."""
        if self.control == "torque":
            self._torque[:] = self.torques(action)
        else:
            self._command(self.targets(action))

    def _apply_torques(self) -> None:
        pybullet.setJointMotorControlArray(
            self.body,
            self.joint_indices,
            pybullet.TORQUE_CONTROL,
            forces=self._torque,
            physicsClientId=self.sim.client,
        )

    def applied_torques(self) -> list[float]:
        if self.control == "torque":
            return list(self._torque)
        states = pybullet.getJointStates(
            self.body, self.joint_indices, physicsClientId=self.sim.client
        )
        return [s[JOINT_STATE_MOTOR_TORQUE] for s in states]

    def randomise(
        self, masses: np.ndarray | None, friction: float | None, strength: np.ndarray | None
    ) -> None:
        cid = self.sim.client
        for k, (index, mass, inertia) in enumerate(self._nominal):
            scale = 1.0 if masses is None else float(masses[k])
            pybullet.changeDynamics(
                self.body,
                index,
                mass=mass * scale,
                localInertiaDiagonal=[value * scale for value in inertia],
                # The ground's is 1 and PyBullet multiplies the two.
                lateralFriction=GROUND_FRICTION if friction is None else friction,
                physicsClientId=cid,
            )
        self._set_strength(strength)

    def payload_state(self) -> PayloadState:
        cid = self.sim.client
        position = pybullet.getBasePositionAndOrientation(self.payload, physicsClientId=cid)[0]

        def touches(other: int) -> bool:
            contacts = pybullet.getContactPoints(self.payload, other, physicsClientId=cid)
            return any(c[CONTACT_DISTANCE] <= CONTACT_SLACK for c in contacts)

        return PayloadState(tuple(position), touches(self.sim.ground), touches(self.body))

    def _command(self, targets: list[float]) -> None:
        pybullet.setJointMotorControlArray(
            self.body,
            self.joint_indices,
            pybullet.POSITION_CONTROL,
            targetPositions=targets,
            forces=self.efforts,
            physicsClientId=self.sim.client,
        )

    def read(self) -> Snapshot:
        """One read of the state: a few engine calls, float math.

        Kept to plain Python floats on purpose: with three to five links, numpy's
        per-call cost would exceed the arithmetic (see bench/evaluation.py, overhead).
        """
        cid = self.sim.client
        body = self.body
        states = pybullet.getJointStates(body, self.joint_indices, physicsClientId=cid)
        poses = [pybullet.getBasePositionAndOrientation(body, physicsClientId=cid)]
        if self._child_indices:
            poses += pybullet.getLinkStates(
                body, self._child_indices, computeForwardKinematics=1, physicsClientId=cid
            )
        touching = [False] * len(poses)
        if self.reads_contacts:
            slot = self._link_slot
            for contact in self.sim.ground_contacts(body):
                if contact[CONTACT_DISTANCE] <= CONTACT_SLACK:
                    touching[slot[contact[CONTACT_LINK_A]]] = True
        return Snapshot(
            [s[JOINT_STATE_POSITION] for s in states],
            [s[JOINT_STATE_VELOCITY] for s in states],
            poses,
            touching,
            self.geometry,
            self._constants,
        )
