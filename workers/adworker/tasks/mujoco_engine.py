"""The MuJoCo engine: the same URDF, ground, clock and motors as PyBullet's simulator
(:mod:`adworker.tasks.simulator`, :mod:`adworker.tasks.robot`), built with
``mujoco.MjSpec`` and read into the same :class:`~adworker.tasks.snapshot.Snapshot`.

The world is the URDF the PyBullet path loads (a design's, or a template's own), with:

- its links kept apart (``fusestatic`` off: a fixed joint's child stays a body of its
  own, as PyBullet keeps it a link), collision shapes only, inertias as written;
- a ground plane (friction ``GROUND_FRICTION``) that the links touch and that is all
  they touch (no self-collision, as PyBullet's ``loadURDF`` without its flag); each link
  takes the task's rolling and spinning friction, as PyBullet's ``changeDynamics``;
- a free joint at the root of a free robot, set down where ``adclient.spawn`` says;
  a fixed-base robot's root welded where its URDF puts it;
- a servo on every driven joint that moves as PyBullet's position-controlled motor
  does, its force capped at the joint's effort. PyBullet's motor drives the joint's
  velocity towards ``0.1 / time_step`` times its position error (its default position
  gain), capped at the joint's velocity limit, with whatever force (within the effort)
  that takes. Here each joint's servo (MuJoCo's ``intvelocity``) follows a setpoint
  that moves, over each control step, at that same rate towards the action's target
  (the exponential approach over the step), capped at the joint's velocity limit; a
  PD spring (``kp`` the effort over ``SERVO_FULL_EFFORT_ERROR`` or a tenth of the
  joint's range, whichever is less, damping ``SERVO_DAMPING_STEPS`` time steps) pulls
  the joint to the setpoint. Under a steady
  load it holds within that spring's give where PyBullet's holds exactly (stand-up's
  arch bent to 1.41 rad holds at 1.39);
- under torque control (``control: torque``), a motor actuator on every driven joint
  instead, its force the action times the joint's effort (capped at the effort, as this
  episode's motor strength scales it);
- a payload (``PayloadSpec``), where a task asks for one: a free box body after the
  robot's, touching the links and the ground;
- the same time step, ``frame_skip`` and gravity; MuJoCo's ``implicitfast`` integrator
  (the servo's damping integrated implicitly, stable at a 120 Hz step).

A snapshot's pose of a link is its centre of mass (``xipos``) and its link frame's
orientation, and its geometry is given in that frame (PyBullet's is its inertial frame,
which for a design link has the link frame's axes). A link touches the ground when
MuJoCo reports a contact of the two (the shapes meet; PyBullet's counts one closer
than ``CONTACT_SLACK``, so a link hovering within 2 mm touches there, not here). The
kinematics and contacts are computed for the state after the control step
(``mj_step`` leaves them at the state before its last integration).

Pictures: the pose is drawn by PyBullet's software renderer (the same URDF posed as
MuJoCo holds it), so a trial's picture and its markers look the same on both engines
and need no OpenGL on the worker.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from adclient.spawn import spawn_pose
from adworker.tasks.engine import (
    CONTACT_SLACK,
    GROUND_FRICTION,
    Camera,
    EngineMeter,
    EngineRobot,
    EngineSimulator,
    JointSpec,
    PayloadSpec,
    PayloadState,
    payload_start,
)
from adworker.tasks.model import RobotModel
from adworker.tasks.snapshot import LinkGeometry, Snapshot

SERVO_FULL_EFFORT_ERROR = 0.2
"""Position error (rad, or m for a prismatic joint) from its setpoint at which a
servo's spring alone reaches the joint's effort (stiffer servos ring on light legs at a
120 Hz step)."""
SERVO_RANGE_FRACTION = 0.1
"""... or this fraction of the joint's range where that is less (a prismatic joint's
range is metres: a 0.3 m rail's servo reaches its effort 3 cm off)."""
SERVO_DAMPING_STEPS = 2.0
"""The servo's damping over its stiffness, in time steps (``kv = kp * 2 * time_step``):
it follows its moving setpoint about this far behind."""
log = logging.getLogger(__name__)


class SimulationDiverged(RuntimeError):
    """MuJoCo found a huge or NaN acceleration (and reset the world to its rest pose, as
    it does): what the episode measured after it would be a fresh start's, so the job
    ends here, naming it, instead of scoring it."""


def _log_warning(message: str) -> None:
    """MuJoCo's warnings to the worker's log, not to ``MUJOCO_LOG.TXT`` in its folder."""
    log.warning("MuJoCo: %s", message)


mujoco.set_mju_user_warning(_log_warning)

PYBULLET_POSITION_GAIN = 0.1
"""PyBullet's default position gain: its motor's velocity target is this times the
error per time step."""

_JOINT_TYPE = {
    "revolute": mujoco.mjtJoint.mjJNT_HINGE,
    "continuous": mujoco.mjtJoint.mjJNT_HINGE,
    "prismatic": mujoco.mjtJoint.mjJNT_SLIDE,
}


class MujocoSimulator(EngineSimulator):
    """One MuJoCo model and its data: a ground plane, gravity, a fixed control period.

    The model is compiled when the robot is added (:meth:`attach`): in MuJoCo the
    whole world is one model.
    """

    def __init__(self, *, time_step: float, frame_skip: int) -> None:
        super().__init__(time_step=time_step, frame_skip=frame_skip)
        self.model: Any = None
        self.data: Any = None
        self._closed = False
        self._urdf_path: str | None = None
        self._fixed_base = False
        self._picture: Any = None
        """(PyBullet simulator, body, joint index by name, base inertial offset)."""

    def attach(self, model: Any, urdf_path: str, *, fixed_base: bool) -> None:
        self.model = model
        self.data = mujoco.MjData(model)
        self._urdf_path = urdf_path
        self._fixed_base = fixed_base

    def step(self, each: Callable[[], None] | None = None) -> None:
        model, data = self.model, self.data
        if each is None:
            mujoco.mj_step(model, data, nstep=self.frame_skip)
        else:
            for _ in range(self.frame_skip):
                mujoco.mj_step(model, data)
                each()
        self.physics_steps += self.frame_skip
        diverged = data.warning[mujoco.mjtWarning.mjWARN_BADQACC]
        if diverged.number:
            raise SimulationDiverged(
                f"the MuJoCo simulation diverged (a huge or NaN acceleration of degree of "
                f"freedom {diverged.lastinfo}, by physics step {self.physics_steps} at a "
                f"{self.time_step:g} s step): the design is "
                "unstable on this engine at this step; PyBullet may simulate it"
            )

    # ---------------------------------------------------------------- pictures

    def _picture_world(self) -> Any:
        if self._picture is None:
            import pybullet

            from adworker.tasks.simulator import Simulator

            sim = Simulator(time_step=self.time_step, frame_skip=self.frame_skip)
            try:
                assert self._urdf_path is not None
                body = sim.load_urdf(self._urdf_path, fixed_base=self._fixed_base)
                joints = {}
                for j in range(pybullet.getNumJoints(body, physicsClientId=sim.client)):
                    info = sim.joint_info(body, j)
                    joints[info.name.decode()] = j
                dynamics = sim.dynamics_info(body, -1)
            except BaseException:
                sim.close()
                raise
            offset = (dynamics.inertial_position, dynamics.inertial_orientation)
            self._picture = (sim, body, joints, offset)
        return self._picture

    def camera(
        self, target: np.ndarray, distance: float, width: int = 320, height: int = 240
    ) -> Camera:
        sim = self._picture_world()[0]
        return sim.camera(target, distance, width, height)

    def render(self, camera: Camera) -> np.ndarray:
        """The current pose drawn by PyBullet's software renderer (see the module
        docstring)."""
        import pybullet

        sim, body, joints, (inertial_position, inertial_orientation) = self._picture_world()
        model, data = self.model, self.data
        mujoco.mj_kinematics(model, data)
        cid = sim.client
        if not self._fixed_base:
            w, x, y, z = data.xquat[1].tolist()
            position, orientation = pybullet.multiplyTransforms(
                data.xpos[1].tolist(), (x, y, z, w), inertial_position, inertial_orientation
            )
            pybullet.resetBasePositionAndOrientation(body, position, orientation, cid)
        for j in range(model.njnt):
            if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE:
                continue
            index = joints.get(model.joint(j).name)
            if index is not None:
                angle = float(data.qpos[model.jnt_qposadr[j]])
                pybullet.resetJointState(body, index, angle, 0.0, cid)
        return sim.render(camera)

    @property
    def connected(self) -> bool:
        return not self._closed

    def close(self) -> None:
        if self._picture is not None:
            self._picture[0].close()
            self._picture = None
        self._closed = True
        self.data = None
        self.model = None


class MujocoMeter(EngineMeter):
    """The servos' applied forces (``actuator_force``) and the joints' velocities after
    every physics step; the figures are :class:`adworker.tasks.robot.MotorMeter`'s."""

    def __init__(self, sim: MujocoSimulator, actuators: list[int], dofs: list[int]) -> None:
        super().__init__(len(actuators), sim.time_step)
        self._data = sim.data
        self._actuators = np.array(actuators)
        self._dofs = np.array(dofs)

    def sample(self) -> None:
        tau = self._data.actuator_force[self._actuators]
        qd = self._data.qvel[self._dofs]
        self.torque_sum += float(np.abs(tau).sum())
        self.episode_energy[-1] += float(np.abs(tau * qd).sum()) * self._time_step
        self.samples += 1


class MujocoRobot(EngineRobot):
    """A robot model in a MuJoCo simulator, built from its URDF (see the module
    docstring); the interface of :class:`~adworker.tasks.engine.EngineRobot`."""

    sim: MujocoSimulator

    def __init__(
        self,
        sim: MujocoSimulator,
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
        what = Path(urdf_path).name
        spec = self._spec(
            str(urdf_path),
            model,
            time_step=sim.time_step,
            fixed_base=fixed_base,
            rolling_friction=rolling_friction,
            spinning_friction=spinning_friction,
            control=control,
        )
        if payload is not None:
            self._add_payload(spec, payload)
        compiled = spec.compile()
        sim.attach(compiled, str(urdf_path), fixed_base=fixed_base)
        links = compiled.nbody - (1 if payload is None else 2)
        self._check_tree(compiled, what, links)
        # The root first, then MuJoCo's body order (depth first through the tree).
        self.link_names = [compiled.body(b).name for b in range(1, links + 1)]
        body_of = {name: b for b, name in enumerate(self.link_names, start=1)}
        self.geometry = [self._geometry(compiled, name, body_of[name]) for name in self.link_names]
        driven = sorted(
            (joint for joint in model.joints if joint.driven), key=lambda j: body_of[j.child]
        )
        if not driven:
            raise ValueError(f"{what}: the robot has no joint to drive")
        self.joints = [JointSpec.of(joint, compiled.joint(joint.name).id) for joint in driven]
        self._qadr = np.array([compiled.jnt_qposadr[j.index] for j in self.joints])
        self._dadr = np.array([compiled.jnt_dofadr[j.index] for j in self.joints])
        self._ctrl = np.array([compiled.actuator(j.name).id for j in self.joints])
        self._setpoint = np.array([compiled.actuator_actadr[k] for k in self._ctrl])
        self._speed = np.array([j.velocity for j in self.joints])
        rate = PYBULLET_POSITION_GAIN / sim.time_step
        period = sim.control_period
        self._approach = (1.0 - math.exp(-rate * period)) / period
        self._scale_joints()
        self._constants = [g.constants() for g in self.geometry]
        self._links = len(self.geometry)
        slot = np.full(compiled.ngeom, -1, dtype=int)
        for g in range(compiled.ngeom):
            body = int(compiled.geom_bodyid[g])
            if 0 < body <= links:
                slot[g] = body - 1
        self._geom_slot = slot
        self._ground = compiled.geom("ground").id
        self._link_bodies = np.arange(1, links + 1)
        self._link_geoms = np.flatnonzero(slot >= 0)
        self._nominal_mass = np.array(compiled.body_mass[1 : links + 1])
        self._nominal_inertia = np.array(compiled.body_inertia[1 : links + 1])
        self.spawn = spawn_pose(model.kinematics, lay_down=model.lay_down, fixed_base=fixed_base)
        """Where every episode starts, before its noise (``adclient.spawn``)."""
        placed = np.array(compiled.qpos0)
        if not fixed_base:
            x, y, z, w = self.spawn.orientation
            placed[0:7] = (*self.spawn.position, w, x, y, z)
        for joint, adr in zip(self.joints, self._qadr, strict=True):
            placed[adr] = self.spawn.joints[joint.name]
        self._placed = placed
        self._payload = -1
        if payload is not None:
            self._payload = compiled.body("payload").id
            self._payload_geom = compiled.geom("payload").id
            start = compiled.jnt_qposadr[compiled.joint("payload").id]
            sim.data.qpos[:] = placed
            mujoco.mj_forward(compiled, sim.data)
            where = payload_start(self, payload)
            placed[start : start + 7] = (*where, 1.0, 0.0, 0.0, 0.0)
            sim.data.qpos[:] = placed
            mujoco.mj_forward(compiled, sim.data)

    @staticmethod
    def _add_payload(spec: Any, payload: PayloadSpec) -> None:
        """A free box body after the robot's: it touches the links and the ground."""
        body = spec.worldbody.add_body()
        body.name = "payload"
        freejoint = body.add_freejoint()
        freejoint.name = "payload"
        box = body.add_geom()
        box.name = "payload"
        box.type = mujoco.mjtGeom.mjGEOM_BOX
        box.size = (payload.size / 2,) * 3
        box.mass = payload.mass
        box.contype = 1
        box.conaffinity = 1
        box.condim = 3
        box.friction = (GROUND_FRICTION, 0.0, 0.0)

    # ----------------------------------------------------------------- building

    @staticmethod
    def _spec(
        urdf_path: str,
        model: RobotModel,
        *,
        time_step: float,
        fixed_base: bool,
        rolling_friction: float,
        spinning_friction: float,
        control: str = "position",
    ) -> Any:
        spec = mujoco.MjSpec.from_file(urdf_path)
        spec.compiler.fusestatic = False
        spec.compiler.discardvisual = True
        # A URDF link without an inertial: a tiny mass, not a compile error.
        spec.compiler.boundmass = 1e-6
        spec.compiler.boundinertia = 1e-10
        spec.option.timestep = time_step
        spec.option.gravity = (0.0, 0.0, -9.81)
        spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
        if rolling_friction > 0:
            condim = 6
        elif spinning_friction > 0:
            condim = 4
        else:
            condim = 3
        for body in spec.bodies:
            for geom in body.geoms:
                # The links touch the ground (contype 1 meets its conaffinity 1), never
                # each other (conaffinity 0). No margin: MuJoCo's contact holds a body
                # at its margin's distance, so a margin would lift the robot off the
                # ground; a contact is reported once the shapes meet.
                geom.contype = 1
                geom.conaffinity = 0
                geom.condim = condim
                geom.friction = (GROUND_FRICTION, spinning_friction, rolling_friction)
        floor = spec.worldbody.add_geom()
        floor.name = "ground"
        floor.type = mujoco.mjtGeom.mjGEOM_PLANE
        floor.size = (0.0, 0.0, 1.0)
        floor.contype = 0
        floor.conaffinity = 1
        floor.condim = 3
        floor.friction = (GROUND_FRICTION, 0.0, 0.0)
        root = spec.body(model.root)
        if root is None:
            raise ValueError(f"the URDF has no link {model.root!r}, the model's root")
        if not fixed_base:
            root.add_freejoint()
        for joint in model.joints:
            if not joint.driven:
                continue
            give = min(SERVO_FULL_EFFORT_ERROR, SERVO_RANGE_FRACTION * (joint.upper - joint.lower))
            kp = joint.effort / give
            servo = spec.add_actuator()
            servo.name = joint.name
            servo.target = joint.name
            servo.trntype = mujoco.mjtTrn.mjTRN_JOINT
            if control == "torque":
                servo.set_to_motor()  # the control is the torque, capped below
            else:
                servo.set_to_intvelocity(kp=kp, kv=kp * SERVO_DAMPING_STEPS * time_step)
                servo.actlimited = mujoco.mjtLimited.mjLIMITED_TRUE
                servo.actrange = (joint.lower, joint.upper)
            servo.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
            servo.forcerange = (-joint.effort, joint.effort)
        return spec

    def _check_tree(self, compiled: Any, what: str, links: int) -> None:
        """The body MuJoCo built is this model's tree (as PyBullet's Robot checks it)."""
        model = self.model
        if links != len(model.shapes):
            raise ValueError(f"{what}: the URDF has {links} links, the model {len(model.shapes)}")
        if compiled.body(1).name != model.root:
            raise ValueError(
                f"{what}: the URDF's root is {compiled.body(1).name!r}, not the model's"
            )
        for joint in model.joints:
            child = compiled.body(joint.child)
            parent = compiled.body(int(compiled.body_parentid[child.id])).name
            if parent != joint.parent:
                raise ValueError(f"{what}: joint {joint.name!r} is not the model's")
            if joint.driven:
                engine = compiled.joint(joint.name)
                if compiled.jnt_type[engine.id] != _JOINT_TYPE[joint.kind]:
                    raise ValueError(f"{what}: joint {joint.name!r} is not {joint.kind}")

    def _geometry(self, compiled: Any, name: str, body: int) -> LinkGeometry:
        shape = self.model.shapes[name]
        centre_of_mass = np.array(compiled.body_ipos[body])
        masses = self.model.masses
        return LinkGeometry(
            name=name,
            index=body,
            kind=shape.kind,
            centre=shape.centre - centre_of_mass,
            points=shape.points - centre_of_mass,
            radius=shape.radius,
            length=shape.length,
            mass=masses[name] if masses is not None else float(compiled.body_mass[body]),
            axis=np.array(shape.axis, dtype=float),
            ball=shape.ball,
        )

    # ---------------------------------------------------------------- stepping

    def reset(self, start: np.ndarray) -> Snapshot:
        model, data = self.sim.model, self.sim.data
        mujoco.mj_resetData(model, data)
        data.qpos[:] = self._placed
        start = np.clip(start, self.lower, self.upper)
        data.qpos[self._qadr] = start
        if self.control == "torque":
            data.ctrl[self._ctrl] = 0.0
        else:
            data.act[self._setpoint] = start
        mujoco.mj_forward(model, data)
        return self.read()

    def motor_meter(self) -> MujocoMeter:
        return MujocoMeter(self.sim, self._ctrl.tolist(), self._dadr.tolist())

    def act(self, action: np.ndarray) -> None:
        data = self.sim.data
        if self.control == "torque":
            data.ctrl[self._ctrl] = self.torques(action)
            return
        setpoint = data.act[self._setpoint]
        speed = self._approach * (np.array(self.targets(action)) - setpoint)
        data.ctrl[self._ctrl] = np.clip(speed, -self._speed, self._speed)

    def applied_torques(self) -> list[float]:
        return list(self.sim.data.actuator_force[self._ctrl].tolist())

    def randomise(
        self, masses: np.ndarray | None, friction: float | None, strength: np.ndarray | None
    ) -> None:
        model = self.sim.model
        scale = np.ones(len(self._link_bodies)) if masses is None else np.asarray(masses)
        model.body_mass[self._link_bodies] = self._nominal_mass * scale
        model.body_inertia[self._link_bodies] = self._nominal_inertia * scale[:, None]
        # MuJoCo takes the larger of two geoms' frictions: the ground's set too.
        value = GROUND_FRICTION if friction is None else friction
        model.geom_friction[self._link_geoms, 0] = value
        model.geom_friction[self._ground, 0] = value
        self._set_strength(strength)
        efforts = np.array(self.efforts)
        model.actuator_forcerange[self._ctrl] = np.stack([-efforts, efforts], axis=1)

    def payload_state(self) -> PayloadState:
        model, data = self.sim.model, self.sim.data
        mujoco.mj_kinematics(model, data)
        mujoco.mj_collision(model, data)
        on_ground = on_robot = False
        if data.ncon:
            contact = data.contact
            geoms = contact.geom[contact.dist <= CONTACT_SLACK]
            mine = geoms[(geoms == self._payload_geom).any(axis=1)]
            other = mine.sum(axis=1) - self._payload_geom
            on_ground = bool((other == self._ground).any())
            on_robot = bool((self._geom_slot[other] >= 0).any())
        x, y, z = data.xpos[self._payload].tolist()
        return PayloadState((x, y, z), on_ground, on_robot)

    def read(self) -> Snapshot:
        model, data = self.sim.model, self.sim.data
        mujoco.mj_kinematics(model, data)
        positions = data.xipos[1 : self._links + 1].tolist()
        poses = list(
            zip(positions, data.xquat[1 : self._links + 1, [1, 2, 3, 0]].tolist(), strict=True)
        )
        touching = [False] * self._links
        if self.reads_contacts:
            mujoco.mj_collision(model, data)
            if data.ncon:
                contact = data.contact
                near = contact.dist <= CONTACT_SLACK
                if self._payload >= 0:  # the links' contacts with the payload are not ground
                    near &= (contact.geom == self._ground).any(axis=1)
                for k in set(self._geom_slot[contact.geom[near]].max(axis=1).tolist()):
                    if k >= 0:
                        touching[k] = True
        return Snapshot(
            data.qpos[self._qadr].tolist(),
            data.qvel[self._dadr].tolist(),
            poses,
            touching,
            self.geometry,
            self._constants,
        )
