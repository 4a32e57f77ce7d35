"""Designs of one tree in one MuJoCo Warp batch (issue 59): ``worlds_per_design`` worlds of
each design, all stepped together by ``mujoco_warp`` (on a GPU, or Warp's CPU device),
their observations, rewards and scores read as torch tensors on that device.

Each design's world is the MuJoCo engine's (:mod:`adworker.tasks.mujoco_engine`): the
model is the one its ``RobotEnv`` compiled from the design's URDF, so the ground, the
servos and the time step are the CPU engine's. The designs must share one tree (the same
bodies, joints, geoms and actuators in the same order: the same topology); what differs
between them (link lengths and radii, joint positions and axes, masses, inertias, joint
ranges, servo gains) goes in Warp's per-world model fields (``put_model(batch_sizes=...)``,
one row per world). A field that differs and that Warp does not batch is refused, naming it
(but :data:`SLEEP_ONLY_FIELDS`). The model's statistics (``stat.meaninertia``, which scales
the solver's tolerance) are world 0's for every world: a design's solver may stop at a
slightly other residual in the batch than alone.

What is computed, per world, as the CPU engine and :class:`~adworker.tasks.base.RobotEnv`
compute it: the servo's velocity command from the action (the same exponential approach
to the target, capped at the joint's speed), ``frame_skip`` physics steps, then the
kinematics and the ground contacts of the state after the step; the observation in
``EngineRobot.observe``'s order; stand-up's metric (the lifted link's centre height while
every foot touches the ground) as the reward; an episode's score its second-half mean.

Resets and seeds: ``reset(seed)`` seeds world i's generator with ``seed + i`` (the batched
env's convention) and every episode's start noise is drawn from it, as ``RobotEnv`` draws
it: world i plays the episodes of a ``RobotEnv`` seeded ``seed + i`` given the same
actions, to float32 (Warp's precision; the CPU engine is float64). Stand-up has no early
end, so all worlds run their episodes in step and reset together.

Only stand-up under position control, without per-episode randomisation, runs here for
now (:func:`check_batchable` says what is refused); the other tasks keep the CPU engines.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import mujoco
import mujoco_warp as mjw
import numpy as np
import torch
import warp as wp

from adworker.tasks.base import RobotEnv
from adworker.tasks.engine import CONTACT_SLACK
from adworker.tasks.mujoco_engine import MujocoSimulator
from adworker.tasks.stand_up import StandUp

# No line per kernel module loaded in the worker's log.
wp.config.log_level = wp.LOG_WARNING

TASKS = ("stand-up",)
"""The tasks whose metric is computed on the batch."""

MAX_WORLDS = 65536
"""The most worlds one batch holds (designs times worlds per design): about 30 KB of
device memory a world for a 3-link robot, so 2 GB at most."""


def default_device() -> str:
    """The first CUDA device where there is one, else Warp's CPU device."""
    wp.init()
    return "cuda:0" if wp.get_cuda_device_count() > 0 else "cpu"


SLEEP_ONLY_FIELDS = ("dof_length",)
"""Unbatched fields that differ between designs of one tree but that only MuJoCo's
sleeping reads (off in the engine's models): world 0's value stands for all."""


def _batchable_fields() -> set[str]:
    fields = set()
    for field in dataclasses.fields(mjw.Model):
        shape = getattr(field.type, "shape", ())
        if shape and shape[0] == "*":
            fields.add(field.name)
    return fields


def _model_arrays() -> set[str]:
    return {
        field.name
        for field in dataclasses.fields(mjw.Model)
        if getattr(field.type, "shape", None) is not None
    }


def check_batchable(env: RobotEnv) -> None:
    """Refuse, naming the reason, an env this batch does not compute as the CPU engine."""
    if env.simulator != "mujoco":
        raise ValueError(f"the Warp batch runs MuJoCo's world, not {env.simulator!r}'s")
    if env.task.name not in TASKS:
        raise ValueError(
            f"task {env.task.name!r} has no batched metric on the GPU path "
            f"(it has: {', '.join(TASKS)})"
        )
    if env.options.control != "position":
        raise ValueError("the Warp batch drives its joints by position control only")
    if env.options.randomises:
        raise ValueError("the Warp batch does not randomise its physics per episode")
    if env.gait_period is not None:
        raise ValueError("the Warp batch has no gait clock")


def per_world_fields(models: Sequence[Any]) -> dict[str, np.ndarray]:
    """The model fields that differ between the designs' compiled models, one row per
    design; ValueError naming the first structural difference (another tree) or a field
    that differs and that Warp cannot hold per world."""
    first = models[0]
    for size in ("nq", "nv", "nu", "na", "nbody", "njnt", "ngeom"):
        sizes = {int(getattr(model, size)) for model in models}
        if len(sizes) > 1:
            raise ValueError(
                f"the designs are not of one tree: their {size} differ {sorted(sizes)}"
            )
    batchable = _batchable_fields()
    differing: dict[str, np.ndarray] = {}
    for name in sorted(_model_arrays()):
        if not hasattr(first, name) or name in SLEEP_ONLY_FIELDS:
            continue
        values = [np.asarray(getattr(model, name)) for model in models]
        if all(np.array_equal(values[0], value) for value in values[1:]):
            continue
        if name not in batchable:
            raise ValueError(
                f"the designs differ in model field {name!r}, which MuJoCo Warp holds once "
                "for every world: they are not of one tree"
            )
        differing[name] = np.stack(values)
    return differing


@dataclasses.dataclass
class _DesignConstants:
    """What the observation, the servo and the metric need of each design, as
    (designs, ...) arrays."""

    lower: np.ndarray
    upper: np.ndarray
    speed: np.ndarray
    inv_velocity: np.ndarray
    qpos: np.ndarray
    """The placed pose of the design (its spawn), before an episode's joint noise."""
    centre: np.ndarray
    """Each link's shape centre in its pose frame."""


def _mujoco_sim(env: RobotEnv) -> MujocoSimulator:
    sim = env.sim
    assert isinstance(sim, MujocoSimulator)  # check_batchable: a MuJoCo env
    return sim


class WarpBatch:
    """``worlds_per_design`` worlds of each env's design in one MuJoCo Warp batch; see the
    module docstring. ``envs``: one stand-up ``RobotEnv`` on MuJoCo per design, their
    designs of one tree and their options the same."""

    def __init__(
        self, envs: Sequence[RobotEnv], worlds_per_design: int, *, device: str | None = None
    ) -> None:
        if not envs:
            raise ValueError("a batch needs at least one design")
        if worlds_per_design < 1:
            raise ValueError("worlds_per_design must be at least 1")
        self.designs = len(envs)
        self.worlds_per_design = worlds_per_design
        self.nworld = self.designs * worlds_per_design
        if self.nworld > MAX_WORLDS:
            raise ValueError(f"a Warp batch holds at most {MAX_WORLDS} worlds, not {self.nworld}")
        for env in envs:
            check_batchable(env)
        first = envs[0]
        for env in envs[1:]:
            if env.options != first.options:
                raise ValueError("the designs of one batch take the same task options")
        self.device = device or default_device()
        self.episode_steps = first.episode_steps
        self.init_noise = first.init_noise
        self.frame_skip = first.sim.frame_skip
        models = [_mujoco_sim(env).model for env in envs]
        robots = [env.robot for env in envs]
        robot = robots[0]
        if any(r.link_names != robot.link_names for r in robots[1:]) or any(
            [j.name for j in r.joints] != [j.name for j in robot.joints] for r in robots[1:]
        ):
            raise ValueError("the designs are not of one tree: their links or joints differ")
        compiled = models[0]
        self.links = len(robot.link_names)
        self.joints = robot.joint_count
        self._qadr = [int(compiled.jnt_qposadr[j.index]) for j in robot.joints]
        self._dadr = [int(compiled.jnt_dofadr[j.index]) for j in robot.joints]
        self._ctrl = [int(compiled.actuator(j.name).id) for j in robot.joints]
        self._setpoint = [int(compiled.actuator_actadr[k]) for k in self._ctrl]
        period = first.sim.control_period
        rate = 0.1 / first.sim.time_step  # PyBullet's position gain, as the CPU servo
        self._approach = float((1.0 - np.exp(-rate * period)) / period)
        task = first.task
        assert isinstance(task, StandUp)  # check_batchable: the one task computed here
        self._lifted = int(task.lifted)
        self._feet = [int(k) for k in task.feet]
        constants = _DesignConstants(
            lower=np.stack([r.lower for r in robots]),
            upper=np.stack([r.upper for r in robots]),
            speed=np.array([[j.velocity for j in r.joints] for r in robots]),
            inv_velocity=np.array([[1.0 / j.velocity for j in r.joints] for r in robots]),
            qpos=np.stack([self._placed(env) for env in envs]),
            centre=np.array([[g.centre for g in r.geometry] for r in robots]),
        )
        ground = compiled.geom("ground").id
        slot = np.full(compiled.ngeom, -1, dtype=np.int64)
        for g in range(compiled.ngeom):
            body = int(compiled.geom_bodyid[g])
            if 0 < body <= self.links:
                slot[g] = body - 1
        self._ground = int(ground)
        differing = per_world_fields(models)
        self.per_world_fields = sorted(differing)
        """The model fields that differ between the designs (one row per world)."""
        design_of_world = np.repeat(np.arange(self.designs), worlds_per_design)
        with wp.ScopedDevice(self.device):
            self.model = mjw.put_model(
                compiled, batch_sizes={name: self.nworld for name in differing}
            )
            for name, rows in differing.items():
                field = getattr(self.model, name)
                values = rows[design_of_world]
                field.assign(values.reshape(field.numpy().shape).astype(field.numpy().dtype))
            self.data = mjw.make_data(compiled, nworld=self.nworld)
        self._torch = wp.device_to_torch(self.device)
        self._views()
        self._design = torch.as_tensor(design_of_world, device=self._torch)

        def per_world(values: np.ndarray) -> torch.Tensor:
            return torch.as_tensor(values[design_of_world], dtype=torch.float32, device=self._torch)

        self._lower = per_world(constants.lower)
        self._upper = per_world(constants.upper)
        self._mid = (self._lower + self._upper) / 2
        self._half = (self._upper - self._lower) / 2
        self._speed = per_world(constants.speed)
        self._inv_velocity = per_world(constants.inv_velocity)
        self._placed_qpos = per_world(constants.qpos)
        self._centre = per_world(constants.centre)
        self._slot = torch.as_tensor(slot, device=self._torch)
        self._generators: list[np.random.Generator] = [
            np.random.default_rng(i) for i in range(self.nworld)
        ]
        self._step = 0
        self._second_half = self.episode_steps // 2
        self._sum = torch.zeros(self.nworld, device=self._torch)
        self.physics_steps = 0
        self._graph: Any = None

    @staticmethod
    def _placed(env: RobotEnv) -> np.ndarray:
        """The design's placed pose: the CPU engine's reset with no noise, read back."""
        env.robot.reset(np.zeros(env.robot.joint_count))
        return np.array(_mujoco_sim(env).data.qpos)

    def _views(self) -> None:
        d = self.data
        self._qpos = wp.to_torch(d.qpos)
        self._qvel = wp.to_torch(d.qvel)
        self._act = wp.to_torch(d.act)
        self._ctrl_view = wp.to_torch(d.ctrl)
        self._xipos = wp.to_torch(d.xipos)
        self._xmat = wp.to_torch(d.xmat)
        contact = d.contact
        self._contact_geom = wp.to_torch(contact.geom)
        self._contact_dist = wp.to_torch(contact.dist)
        self._contact_world = wp.to_torch(contact.worldid)
        self._nacon = wp.to_torch(d.nacon)

    @property
    def observation_size(self) -> int:
        return 2 * self.joints + 4 + 2 * self.links

    # ------------------------------------------------------------------ episodes

    def reset(self, seed: int | None = None) -> torch.Tensor:
        """Every world back to its placed pose with its joints at this episode's noise
        (drawn from world i's generator, seeded ``seed + i`` when ``seed`` is given)."""
        if seed is not None:
            self._generators = [np.random.default_rng(seed + i) for i in range(self.nworld)]
        noise = np.stack(
            [g.uniform(-self.init_noise, self.init_noise, self.joints) for g in self._generators]
        )
        start = torch.as_tensor(noise, dtype=torch.float32, device=self._torch)
        start = torch.minimum(torch.maximum(start, self._lower), self._upper)
        with wp.ScopedDevice(self.device):
            mjw.reset_data(self.model, self.data)
            self._qpos[:] = self._placed_qpos
            self._qpos[:, self._qadr] = start
            self._act[:, self._setpoint] = start
            mjw.forward(self.model, self.data)
        self._step = 0
        self._sum.zero_()
        return self._observe()[0]

    def step(self, actions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
        """One control step of every world: (observation, reward, scores), ``scores`` the
        episodes' scores where this step ended them (then the worlds are reset and the
        observation is the next episode's first), else None."""
        actions = torch.clamp(actions.to(self._torch, torch.float32), -1.0, 1.0)
        target = self._mid + actions * self._half
        setpoint = self._act[:, self._setpoint]
        command = torch.clamp(self._approach * (target - setpoint), -self._speed, self._speed)
        self._ctrl_view[:, self._ctrl] = command
        self._physics()
        self.physics_steps += self.nworld * self.frame_skip
        observation, metric = self._observe()
        if self._step >= self._second_half:
            self._sum += metric
        self._step += 1
        if self._step < self.episode_steps:
            return observation, metric, None
        scores = self._sum / (self.episode_steps - self._second_half)
        return self.reset(), metric, scores

    def _physics(self) -> None:
        with wp.ScopedDevice(self.device):
            if self._graph is None and wp.get_device(self.device).is_cuda:
                with wp.ScopedCapture() as capture:
                    self._physics_launches()
                self._graph = capture.graph
            if self._graph is not None:
                wp.capture_launch(self._graph)
            else:
                self._physics_launches()

    def _physics_launches(self) -> None:
        for _ in range(self.frame_skip):
            mjw.step(self.model, self.data)
        # The kinematics and contacts of the state after the step (the CPU engine's read).
        mjw.kinematics(self.model, self.data)
        mjw.collision(self.model, self.data)

    def _touching(self) -> torch.Tensor:
        touching = torch.zeros(self.nworld, self.links, dtype=torch.bool, device=self._torch)
        count = min(int(self._nacon[0].item()), self._contact_dist.shape[0])
        if count:
            geom = self._contact_geom[:count].long()
            near = (self._contact_dist[:count] <= CONTACT_SLACK) & (geom == self._ground).any(1)
            other = geom.sum(1) - self._ground
            slot = self._slot[other]
            near &= slot >= 0
            touching[self._contact_world[:count].long()[near], slot[near]] = True
        return touching

    def _observe(self) -> tuple[torch.Tensor, torch.Tensor]:
        links = slice(1, self.links + 1)
        q = self._qpos[:, self._qadr]
        qd = self._qvel[:, self._dadr]
        rows = self._xmat[:, links, 2, :]
        centre_z = self._xipos[:, links, 2] + (rows * self._centre).sum(-1)
        touching = self._touching()
        observation = torch.cat(
            [
                (q - self._mid) / self._half,
                qd * self._inv_velocity,
                rows[:, 0, :],
                self._xipos[:, 1, 2:3],
                centre_z,
                touching.float(),
            ],
            dim=1,
        )
        feet = touching[:, self._feet].all(1)
        metric = torch.where(feet, centre_z[:, self._lifted], torch.zeros_like(centre_z[:, 0]))
        return torch.nan_to_num(observation), torch.nan_to_num(metric)

    def design_of_world(self) -> torch.Tensor:
        """The design (index into ``envs``) each world simulates."""
        return self._design


def mujoco_version() -> str:
    """The MuJoCo (C) and MuJoCo Warp versions, for a report."""
    from importlib.metadata import version

    return f"mujoco {mujoco.__version__}, mujoco-warp {version('mujoco-warp')}"
