"""A task environment: a simulator, a robot and a task, composed into one Gymnasium env.

The split follows panda-gym: the simulator owns the engine's world (world, clock,
camera), the robot is the typed Design in it (joints, shapes, state reads, motor
commands), and a :class:`Task` reads both to say what the robot is asked to do (metric,
reward, termination, observation extras, reset hook, metrics of its own, points marked
in the picture). :class:`RobotEnv` runs the loop. Simulator and robot are those of the
engine a study names (``task.simulator``: PyBullet by default, or MuJoCo), through the
interface of :mod:`adworker.tasks.engine`, so a task is written once for both.

Each control step runs ``frame_skip`` physics steps, then reads the state once into a
:class:`~adworker.tasks.snapshot.Snapshot`. The task turns the snapshot into its
*metric* (the quantity the score is made of) and its reward. By default the *score*
of an episode is the mean metric over its second half, so a design is judged on the
pose it holds, not on the transient that gets it there; a task may score otherwise,
and says how in words beside its rule (``Task.score_rule``: the curve's text).

Evaluation episodes are deterministic for a given seed: ``reset`` restores a state
saved at build time (positions, velocities and contact caches) before applying the
seeded initial perturbation, so an episode's outcome depends only on the seed and
the policy, never on what ran before it. ``meter_motors`` meters the episodes that
follow (the evaluation's): the motors' effort and energy, read after every physics
step (:class:`~adworker.tasks.robot.MotorMeter`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar, Generic, TypeVar

import gymnasium as gym
import numpy as np

from adclient.designs import Design
from adclient.plugins import SimulatorOptions, catalogue
from adclient.urdf_model import read_urdf
from adworker.tasks.build import build_engine
from adworker.tasks.engine import (
    Camera,
    EngineMeter,
    EngineRobot,
    EngineSimulator,
    PayloadSpec,
)
from adworker.tasks.markers import Marker, checked_markers, draw_markers
from adworker.tasks.model import RobotModel, model_of_design, model_of_urdf
from adworker.tasks.snapshot import Snapshot

DEFAULT_EPISODE_STEPS = 32
"""A task's episode length unless the task or ``options.episode_steps`` says otherwise."""

OptionsT = TypeVar("OptionsT", bound=SimulatorOptions)


SECOND_HALF_MEAN = "the per-step metric's second-half mean"
""":func:`episode_score` in words: the default ``Task.score_rule``."""


def episode_score(metric: list[float] | np.ndarray) -> float:
    """Mean of the per-step metric over the second half of an episode."""
    values = np.asarray(metric, dtype=float)
    if values.size == 0:
        return 0.0
    return float(values[values.size // 2 :].mean())


@dataclass
class EpisodeRecord:
    score_of: Callable[[list[float]], float]
    metric: list[float] = field(default_factory=list)

    def score(self) -> float:
        return self.score_of(self.metric)


class Task(Generic[OptionsT]):
    """What the robot is asked to do; subclasses override the hooks they need.

    A task is built after the robot, so it can look links up by name
    (``robot.link_index``) and keep what it needs from ``options`` (its options
    model, validated: the one place its defaults live).
    """

    name: ClassVar[str]
    fixed_base: ClassVar[bool] = False
    """The robot's root is fixed where its URDF puts it, as the task's declaration says
    (``TaskSpec.fixed_base``); else it is set down free (``adclient.spawn``)."""
    reads_contacts: ClassVar[bool] = True
    """Whether each step reads ground contacts (observed as one flag per link)."""
    default_episode_steps: ClassVar[int] = DEFAULT_EPISODE_STEPS
    score_rule: ClassVar[str] = SECOND_HALF_MEAN
    """What :meth:`score` computes from the per-step metric, in words (``curve.json``'s
    ``score``): a task that overrides ``score`` declares its own beside it, as the class
    that defines ``score`` states it (:meth:`score_text`)."""

    def __init__(self, robot: EngineRobot, sim: EngineSimulator, options: OptionsT) -> None:
        self.robot = robot
        self.sim = sim
        self.options = options
        self.gait_period: float | None = None
        """Seconds per cycle of a gait clock the policy sees, for a task done by repeating a
        motion (walking); None: no clock. See :class:`RobotEnv`."""
        self.rng = np.random.default_rng(0)
        """The episode's random numbers (the env's, seeded by ``reset``): what a task
        draws per episode (targets) it draws from this in :meth:`reset`."""

    @classmethod
    def payload(cls, options: OptionsT) -> PayloadSpec | None:
        """A box the robot carries, built into its world (None: none)."""
        return None

    @classmethod
    def make_env(
        cls,
        *,
        design: Design | None,
        urdf_path: str | Path,
        options: OptionsT,
        render_mode: str | None = None,
        simulator: str = "pybullet",
    ) -> RobotEnv:
        """This task's environment for one design (its URDF written at ``urdf_path``), or
        for a template's robot (``design`` None: the URDF is all there is), on the engine
        ``simulator``: the factory a task declaration names."""
        return RobotEnv(
            cls,
            design=design,
            urdf_path=urdf_path,
            options=options,
            render_mode=render_mode,
            simulator=simulator,
        )

    def observation_size(self) -> int:
        return 0

    def observation(self, snapshot: Snapshot) -> list[float]:
        """Extras after the robot's own observation."""
        return []

    def reset(self, snapshot: Snapshot) -> None:
        """Called with the first snapshot of every episode."""

    def metric(self, snapshot: Snapshot) -> float:
        """The per-step quantity an episode's score is made of."""
        raise NotImplementedError

    def reward(self, snapshot: Snapshot, metric: float) -> float:
        return metric

    def terminated(self, snapshot: Snapshot) -> bool:
        """Whether the episode ends here, before its time is up."""
        return False

    def score(self, metric: list[float]) -> float:
        """An episode's score from its per-step metric."""
        return episode_score(metric)

    @classmethod
    def score_text(cls) -> str:
        """:meth:`score`'s rule in words: the nearest ``score_rule`` declared no further up
        than the ``score`` it runs, so a subclass that changes the rule without saying so
        is not described by its parent's words; without one, that ``score``'s docstring's
        first line, else its name."""
        for owner in cls.__mro__:
            declared = vars(owner)
            rule = declared.get("score_rule")
            if isinstance(rule, str):
                return rule
            if "score" in declared:
                doc = (declared["score"].__doc__ or "").strip()
                if doc:
                    return doc.splitlines()[0].rstrip(".")
                return f"the task's own score of its per-step metric ({owner.__qualname__}.score)"
        return SECOND_HALF_MEAN

    def metrics(self, snapshot: Snapshot) -> Mapping[str, float]:
        """The task's own metrics of an evaluation episode, ``snapshot`` its last: the
        trial reports each as ``task.<name>``, its mean over the evaluation episodes
        (names and values checked: :mod:`adworker.task_metrics`)."""
        return {}

    def markers(self, snapshot: Snapshot) -> Sequence[Marker]:
        """Points to mark in the trial's picture of ``snapshot`` (``robot.png``: the last
        evaluation episode's final pose), framed with the robot
        (:mod:`adworker.tasks.markers`)."""
        return ()


def robot_model(design: Design | None, urdf_path: str | Path) -> RobotModel:
    """A design's model, or, without one, the model of the URDF at ``urdf_path``."""
    if design is not None:
        return model_of_design(design)
    return model_of_urdf(read_urdf(Path(urdf_path).read_text()))


class RobotEnv(gym.Env[np.ndarray, np.ndarray]):
    """One design doing one task in its own simulator; see the module docstring.

    Observation: the robot's (``Robot.observe``), then the task's extras, then, for a
    task with a ``gait_period``, a clock: (sin, cos) of the phase 2 pi t / period, t the
    time since the episode began. A policy without memory (an MLP, a periodic gait)
    can then repeat a motion. Action: one value in [-1, 1] per joint
    (``Robot.targets``).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 30}

    def __init__(
        self,
        task: type[Task[OptionsT]],
        *,
        design: Design | None,
        urdf_path: str | Path,
        options: OptionsT,
        render_mode: str | None = None,
        simulator: str = "pybullet",
    ) -> None:
        super().__init__()
        self.options = options
        self.simulator = simulator
        self.design = design
        self.urdf_path = Path(urdf_path)
        """What this env was built of: another world of it is built the same way
        (:mod:`adworker.batched`)."""
        self.render_mode = render_mode
        self.episode_steps = options.episode_steps or task.default_episode_steps
        self.init_noise = options.init_noise
        if self.episode_steps < 2:
            raise ValueError("episode_steps >= 2 required")
        declared = catalogue().tasks.get(task.name)
        if declared is not None and declared.fixed_base != task.fixed_base:
            raise ValueError(
                f"task {task.name!r}: its class has fixed_base = {task.fixed_base}, its "
                f"declaration (TaskSpec) {declared.fixed_base}: the server would say the "
                "robot starts where the worker does not put it"
            )
        self.sim, self.robot = build_engine(
            simulator,
            model=robot_model(design, urdf_path),
            urdf_path=urdf_path,
            fixed_base=task.fixed_base,
            reads_contacts=task.reads_contacts,
            time_step=options.time_step,
            frame_skip=options.frame_skip,
            rolling_friction=options.rolling_friction,
            spinning_friction=options.spinning_friction,
            control=options.control,
            payload=task.payload(options),
        )
        try:
            self.task: Task[OptionsT] = task(self.robot, self.sim, options)
        except BaseException:
            self.sim.close()
            raise
        self.action_space = gym.spaces.Box(
            -1.0, 1.0, shape=(self.robot.joint_count,), dtype=np.float32
        )
        self.gait_period = self.task.gait_period
        self._phase_per_step = (
            None
            if self.gait_period is None
            else 2.0 * math.pi * self.sim.control_period / self.gait_period
        )
        size = self.robot.observation_size() + self.task.observation_size()
        size += 0 if self.gait_period is None else 2
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, shape=(size,), dtype=np.float32)
        self.record = EpisodeRecord(self.task.score)
        self._step_count = 0
        self._last: Snapshot | None = None
        self.meter: EngineMeter | None = None
        self._meter_each: Callable[[], None] | None = None

    @property
    def joint_count(self) -> int:
        return self.robot.joint_count

    @property
    def score_text(self) -> str:
        """What an episode's score is, in words: its task's declared rule
        (:meth:`Task.score_text`)."""
        return self.task.score_text()

    @property
    def sim_steps(self) -> int:
        """Physics steps simulated so far, all episodes together."""
        return self.sim.physics_steps

    def meter_motors(self) -> EngineMeter:
        """Meter the motors' effort and energy (:class:`EngineMeter`) of every episode
        from the next ``reset`` on (the evaluation episodes; training runs unmetered,
        saving a state read per physics step)."""
        self.meter = self.robot.motor_meter()
        self._meter_each = None
        return self.meter

    def _observe(self, snapshot: Snapshot) -> np.ndarray:
        values = self.robot.observe(snapshot)
        values += self.task.observation(snapshot)
        if self._phase_per_step is not None:
            phase = self._phase_per_step * self._step_count
            values += (math.sin(phase), math.cos(phase))
        return np.array(values, dtype=np.float32)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        noise = self.np_random.uniform(-self.init_noise, self.init_noise, self.robot.joint_count)
        if self.options.randomises:
            self._randomise()
        snapshot = self.robot.reset(noise)
        self.task.rng = self.np_random
        self.task.reset(snapshot)
        self.record = EpisodeRecord(self.task.score)
        self._step_count = 0
        self._last = snapshot
        if self.meter is not None:
            self.meter.begin_episode()
            self._meter_each = self.meter.sample
        return self._observe(snapshot), {}

    def _randomise(self) -> None:
        """This episode's physics, drawn from the episode's seeded random numbers (after
        its joint noise, so an episode without randomisation starts as before): a mass
        scale per link, one friction, a strength per joint."""
        options, rng = self.options, self.np_random
        masses = friction = strength = None
        if options.mass_scale is not None:
            masses = rng.uniform(*options.mass_scale, len(self.robot.geometry))
        if options.friction is not None:
            friction = float(rng.uniform(*options.friction))
        if options.motor_strength is not None:
            strength = rng.uniform(*options.motor_strength, self.robot.joint_count)
        self.robot.randomise(masses, friction, strength)

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        self.robot.act(action)
        self.sim.step(self._meter_each)
        snapshot = self.robot.read()
        self._last = snapshot
        task = self.task
        metric = task.metric(snapshot)
        self.record.metric.append(metric)
        self._step_count += 1
        terminated = task.terminated(snapshot)
        truncated = self._step_count >= self.episode_steps
        info: dict[str, Any] = {"score": self.record.score()} if terminated or truncated else {}
        reward = float(task.reward(snapshot, metric))
        return self._observe(snapshot), reward, terminated, truncated, info

    def snapshot(self) -> Snapshot:
        if self._last is None:
            self._last = self.robot.read()
        return self._last

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        return self.render_image()

    def task_metrics(self) -> Mapping[str, float]:
        """The task's own metrics of the episode that has just ended (``Task.metrics``
        of its last snapshot), as the task returned them."""
        return self.task.metrics(self.snapshot())

    def camera(self, width: int = 320, height: int = 240) -> tuple[Camera, list[Marker]]:
        """The camera of the current pose's picture, framing the whole robot and the
        points the task marks, and those markers (checked)."""
        snapshot = self.snapshot()
        markers = checked_markers(self.task.markers(snapshot))
        target, distance = self.robot.camera(snapshot, [m.position for m in markers])
        return self.sim.camera(target, distance, width, height), markers

    def render_image(self, width: int = 320, height: int = 240) -> np.ndarray:
        """The current pose, the whole robot and the task's markers in view."""
        camera, markers = self.camera(width, height)
        return draw_markers(self.sim.render(camera), camera, markers)

    def close(self) -> None:
        self.sim.close()
        super().close()
