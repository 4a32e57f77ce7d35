"""The seam between the tasks and a physics engine: what a task and ``RobotEnv`` use of
the simulator, the robot in it and its motor meter, whichever engine runs them.

Two engines implement it: PyBullet (:mod:`adworker.tasks.simulator` and
:mod:`adworker.tasks.robot`, the default) and MuJoCo
(:mod:`adworker.tasks.mujoco_engine`). A study names one with ``task.simulator``;
:func:`adworker.tasks.build.build_engine` builds the simulator and the robot on it
from the same URDF and model. Both read the state into the same
:class:`~adworker.tasks.snapshot.Snapshot` (the links' centre-of-mass positions and
frame orientations, joint positions and velocities, ground contacts) and meter the same
motor quantities, so a task is written once against this module's classes and scores the
same quantities on either engine.

What does not depend on the engine lives here: the mapping of an action onto the joints'
targets (position control) or torques (torque control), the motors' power as a fraction
of their peak, a payload's starting place, the robot's own observation, link lookup and
the camera's framing. Each engine randomises an episode's masses, friction and motor
strength (:meth:`EngineRobot.randomise`) and carries a payload the same way.
"""

from __future__ import annotations

import math
import warnings
from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from adworker.tasks.model import JointModel, RobotModel
from adworker.tasks.snapshot import POSE_ORIENTATION, POSE_POSITION, LinkGeometry, Snapshot

CONTACT_SLACK = 0.002
"""A link touches the ground when the engine reports a contact closer than this (m)."""
GROUND_FRICTION = 1.0


class Camera(NamedTuple):
    """A camera as PyBullet takes it (view and projection matrices, column-major) and
    the size of its pictures."""

    view: tuple[float, ...]
    projection: tuple[float, ...]
    width: int
    height: int

    def pixel(self, point: Sequence[float]) -> tuple[float, float] | None:
        """Where the world point ``point`` appears in this camera's pictures: (column,
        row) from the top-left corner, in pixels (outside the picture when out of
        view), or None when it is behind the camera."""
        view = np.reshape(self.view, (4, 4), order="F")
        projection = np.reshape(self.projection, (4, 4), order="F")
        clip = projection @ view @ np.array([*point, 1.0], dtype=float)
        if clip[3] <= 0.0:
            return None
        x, y = clip[0] / clip[3], clip[1] / clip[3]
        return (x + 1.0) / 2.0 * self.width, (1.0 - y) / 2.0 * self.height


@dataclass
class JointSpec:
    index: int
    """The engine's joint index (PyBullet's: also the index of its child link)."""
    name: str
    child: str
    lower: float
    upper: float
    effort: float
    velocity: float

    @classmethod
    def of(cls, joint: JointModel, index: int) -> JointSpec:
        """A model's driven joint as the engine's joint ``index``."""
        return cls(
            index=index,
            name=joint.name,
            child=joint.child,
            lower=joint.lower,
            upper=joint.upper,
            effort=joint.effort,
            velocity=joint.velocity,
        )


CONTROLS = ("position", "torque")
"""What an action commands (``SimulatorOptions.control``): joint position targets, or
joint torques as fractions of each joint's effort."""


@dataclass(frozen=True)
class PayloadSpec:
    """A box of ``mass`` kg and side ``size`` m set down resting on top of the link
    ``link`` (None: the root) at the start of every episode (a task's ``Task.payload``):
    a body of its own that touches the robot's links and the ground, and so can be
    dropped."""

    link: str | None
    mass: float
    size: float


@dataclass(frozen=True)
class PayloadState:
    """Where the payload is after a control step, and what it touches."""

    position: tuple[float, float, float]
    on_ground: bool
    on_robot: bool


def payload_start(robot: EngineRobot, payload: PayloadSpec) -> tuple[float, float, float]:
    """Where ``payload`` starts: its centre above its link's shape centre, its bottom
    1 mm above the link's top, the robot as placed."""
    snapshot = robot.read()
    k = 0 if payload.link is None else robot.link_index(payload.link)
    x, y, _ = (float(v) for v in snapshot.centre(k))
    return x, y, snapshot.top[k] + payload.size / 2 + 0.001


class EngineSimulator(ABC):
    """One world of one engine: gravity, a ground plane, a fixed control period (one
    control step is ``frame_skip`` physics steps of ``time_step`` seconds), a camera."""

    def __init__(self, *, time_step: float, frame_skip: int) -> None:
        if frame_skip < 1 or time_step <= 0:
            raise ValueError("frame_skip >= 1 and time_step > 0 required")
        self.time_step = time_step
        self.frame_skip = frame_skip
        self.physics_steps = 0
        """Physics steps simulated so far."""

    @property
    def control_period(self) -> float:
        """Seconds of simulated time per control step."""
        return self.time_step * self.frame_skip

    @abstractmethod
    def step(self, each: Callable[[], None] | None = None) -> None:
        """One control step: ``frame_skip`` physics steps, ``each`` called after every
        one (a meter that reads what happened during that physics step)."""

    @abstractmethod
    def camera(
        self, target: np.ndarray, distance: float, width: int = 320, height: int = 240
    ) -> Camera:
        """A camera at a fixed angle, ``distance`` from ``target``."""

    @abstractmethod
    def render(self, camera: Camera) -> np.ndarray:
        """The world as ``camera`` sees it: an RGB array."""

    @property
    @abstractmethod
    def connected(self) -> bool: ...

    @abstractmethod
    def close(self) -> None: ...


class EngineMeter(ABC):
    """The joint motors' effort and mechanical energy over episodes, read after every
    physics step (``EngineSimulator.step``'s ``each``); see
    :class:`adworker.tasks.robot.MotorMeter` for what each figure means."""

    def __init__(self, joint_count: int, time_step: float) -> None:
        self._joint_count = joint_count
        self._time_step = time_step
        self.episode_energy: list[float] = []
        """Each metered episode's energy (J), in order; the last one may be running."""
        self.torque_sum = 0.0
        """Sum of |tau| over all metered physics steps and joints (N m)."""
        self.samples = 0
        """Metered physics steps, all episodes together."""

    def begin_episode(self) -> None:
        self.episode_energy.append(0.0)

    @abstractmethod
    def sample(self) -> None:
        """Read the torques and velocities of the physics step just taken."""

    @property
    def effort(self) -> float:
        """Mean |torque| per joint per physics step (N m); 0 before any step."""
        if not self.samples:
            return 0.0
        return self.torque_sum / (self.samples * self._joint_count)

    @property
    def energy(self) -> float:
        """Mean energy per metered episode (J); 0 before any episode."""
        if not self.episode_energy:
            return 0.0
        return math.fsum(self.episode_energy) / len(self.episode_energy)


class EngineRobot(ABC):
    """A robot model in an engine's simulator: its joints, link shapes, state reads and
    motor commands. A subclass builds the body and sets the attributes below, then
    calls :meth:`_scale_joints`."""

    def __init__(
        self,
        sim: EngineSimulator,
        model: RobotModel,
        *,
        fixed_base: bool,
        reads_contacts: bool,
        control: str = "position",
    ) -> None:
        if control not in CONTROLS:
            raise ValueError(f"control {control!r} is not one ({', '.join(CONTROLS)})")
        self.sim = sim
        self.model = model
        self.fixed_base = fixed_base
        self.reads_contacts = reads_contacts
        self.control = control
        """``position``: an action is joint targets (:meth:`targets`); ``torque``: joint
        torques (:meth:`torques`)."""

    geometry: list[LinkGeometry]
    """Per link, in the snapshot's order (the root first, then depth first)."""
    link_names: list[str]
    joints: list[JointSpec]
    """The driven joints, in the action's order."""
    spawn: Any
    """Where every episode starts, before its noise (``adclient.spawn``)."""

    def _scale_joints(self) -> None:
        self.lower = np.array([joint.lower for joint in self.joints])
        self.upper = np.array([joint.upper for joint in self.joints])
        self._half_span = [(joint.upper - joint.lower) / 2 for joint in self.joints]
        self._mid = [(joint.upper + joint.lower) / 2 for joint in self.joints]
        self._inv_half = [2.0 / (joint.upper - joint.lower) for joint in self.joints]
        self._inv_velocity = [1.0 / joint.velocity for joint in self.joints]
        self.efforts = [joint.effort for joint in self.joints]
        self._nominal_efforts = np.array(self.efforts)
        self._peak_power = math.fsum(joint.effort * joint.velocity for joint in self.joints)

    def randomise(
        self, masses: np.ndarray | None, friction: float | None, strength: np.ndarray | None
    ) -> None:
        """This episode's physics: each link's mass (and inertia) scaled by ``masses`` (in
        ``geometry``'s order), the links' friction with the ground ``friction``, each
        joint's effort scaled by ``strength`` (None: as built). Called before
        :meth:`reset`; it holds until the next call."""
        raise NotImplementedError(f"{type(self).__name__} does not randomise its physics")

    def _set_strength(self, strength: np.ndarray | None) -> None:
        scale = np.ones(len(self.joints)) if strength is None else np.asarray(strength)
        self.efforts = (self._nominal_efforts * scale).tolist()

    def torques(self, action: np.ndarray) -> list[float]:
        """Joint torques (forces, for a prismatic joint): the action in [-1, 1] times
        each joint's effort (this episode's, :meth:`randomise`)."""
        values = action.tolist() if isinstance(action, np.ndarray) else list(action)
        if len(values) != len(self.efforts):
            raise ValueError(f"expected {len(self.efforts)} joint torques, got {len(values)}")
        return [
            (1.0 if a > 1.0 else -1.0 if a < -1.0 else a) * effort
            for a, effort in zip(values, self.efforts, strict=True)
        ]

    def applied_torques(self) -> list[float]:
        """The torque each driven joint's motor applied in the last physics step."""
        raise NotImplementedError(f"{type(self).__name__} does not read its motors' torques")

    def power_fraction(self, snapshot: Snapshot) -> float:
        """The motors' mechanical power at ``snapshot`` (sum of |torque x joint speed|,
        the last physics step's torques) over their peak (sum of effort x velocity
        limit, as built): 0 at rest, 1 with every motor at full torque and full speed."""
        power = math.fsum(
            abs(tau * qd) for tau, qd in zip(self.applied_torques(), snapshot.qd, strict=True)
        )
        return power / self._peak_power if self._peak_power > 0 else 0.0

    def payload_state(self) -> PayloadState:
        """The payload's state (a robot built with a :class:`PayloadSpec`)."""
        raise NotImplementedError(f"{type(self).__name__} carries no payload")

    @abstractmethod
    def reset(self, start: np.ndarray) -> Snapshot:
        """Back to the placed pose with the joints at ``start`` (clipped to their limits),
        holding there."""

    @abstractmethod
    def act(self, action: np.ndarray) -> None:
        """Command the joints towards the action's targets (takes effect as the simulator
        steps)."""

    @abstractmethod
    def read(self) -> Snapshot:
        """One read of the state."""

    @abstractmethod
    def motor_meter(self) -> EngineMeter:
        """A new meter of this robot's motors."""

    @property
    def joint_count(self) -> int:
        return len(self.joints)

    def observation_size(self) -> int:
        """Joint positions and velocities; for a free base its tilt, height and the links'
        heights; one ground-contact flag per link where contacts are read."""
        size = 2 * len(self.joints)
        if not self.fixed_base:
            size += 4 + len(self.geometry)
        if self.reads_contacts:
            size += len(self.geometry)
        return size

    def targets(self, action: np.ndarray) -> list[float]:
        """Joint position targets: the action in [-1, 1] mapped onto [lower, upper]."""
        values = action.tolist() if isinstance(action, np.ndarray) else list(action)
        if len(values) != len(self._mid):
            raise ValueError(f"expected {len(self._mid)} joint targets, got {len(values)}")
        return [
            mid + (1.0 if a > 1.0 else -1.0 if a < -1.0 else a) * half
            for a, mid, half in zip(values, self._mid, self._half_span, strict=True)
        ]

    def observe(self, snapshot: Snapshot) -> list[float]:
        """The robot's own senses, in the order of :meth:`observation_size`."""
        values = [
            (q - mid) * inv
            for q, mid, inv in zip(snapshot.q, self._mid, self._inv_half, strict=True)
        ]
        values += [qd * inv for qd, inv in zip(snapshot.qd, self._inv_velocity, strict=True)]
        if not self.fixed_base:
            # A fixed base never moves: its pose and its links' heights (functions of the
            # joint angles) would add nothing.
            pose = snapshot.poses[0]
            x, y, z, w = pose[POSE_ORIENTATION]
            # World +z seen from the root frame: the body's tilt.
            values += (2.0 * (x * z - y * w), 2.0 * (y * z + x * w), 1.0 - 2.0 * (x * x + y * y))
            values.append(pose[POSE_POSITION][2])
            values += snapshot.centre_z
        if self.reads_contacts:
            values += snapshot.touching
        return values

    def link_index(self, name: str) -> int:
        """The index ``k`` of a link (a design's instance name, or a URDF's link name) in
        the snapshot's arrays and ``geometry``; KeyError naming it if there is none."""
        try:
            return self.link_names.index(name)
        except ValueError:
            raise KeyError(f"the robot has no link named {name!r}") from None

    def link_position(self, name: str) -> int:
        """Deprecated alias of :meth:`link_index` (it returns an index, not a position),
        kept for one release."""
        warnings.warn(
            "Robot.link_position is deprecated: it returns an index, use Robot.link_index",
            DeprecationWarning,
            stacklevel=2,
        )
        return self.link_index(name)

    def camera(
        self, snapshot: Snapshot, also: Sequence[Sequence[float]] = ()
    ) -> tuple[np.ndarray, float]:
        """Where a camera should look to frame the whole robot and the points ``also``,
        and from how far."""
        points = np.array(
            [snapshot.centre(k) for k in range(len(self.geometry))] + [list(p) for p in also]
        )
        extent = float(np.ptp(points, axis=0).max()) + max(
            (g.length for g in self.geometry), default=0.4
        )
        return points.mean(axis=0), max(1.0, 1.6 * extent)
