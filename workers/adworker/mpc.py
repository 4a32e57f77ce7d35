"""The ``mpc`` learner (issue 59): sampling-based model-predictive control on MuJoCo, a
training-free evaluator that judges what a design can do in seconds.

Nothing is trained. The policy it returns plans at every ``replan_every``-th control step
of the evaluation episode from the world's current state, as MuJoCo MPC's predictive
sampling does (Howell et al. 2022, arXiv 2212.00541): a plan is ``knots`` action knots
over ``horizon`` control steps (linear between them, held after the last); ``samples``
sequences are drawn around the current nominal plan (the nominal itself among them, its
knots shifted by the steps since it was made), each is rolled out from an exact copy of
the world's ``MjData`` (``mujoco.mj_copyData``: positions, velocities, servo setpoints,
contacts' warm start) and scored by the task's own reward summed over the rollout, and the
best becomes the nominal plan; its first action is applied. ``method: cem`` instead refits
a Gaussian to the ``cem_elites`` best samples ``cem_iterations`` times.

A rollout steps the copy through the job's own robot and simulator (``robot.act``,
``sim.step``, ``robot.read``: the same servo law, ``frame_skip`` physics steps in one
``mj_step`` call in C, the same snapshot), with the world's data swapped for the copy's
while it runs, so the planner's model is the engine the episode is scored on, a
plugin's task included. The task's state (walk-forward's distance so far) is kept
before each rollout and restored after it. A rollout whose task ends the episode early
(``Task.terminated``) ranks below every one that does not; one that diverges
(:class:`~adworker.tasks.mujoco_engine.SimulationDiverged`, its MuJoCo warning not
logged) ranks last, and so does one whose world gains more mechanical energy (gravity's
potential and the kinetic, ``mj_energyPos``/``mj_energyVel``) than its motors did work
(the motor meter's sum of |torque x joint speed| over its physics steps), beyond
:data:`WORK_SLACK` and :data:`ENERGY_SLACK`: a strong optimiser otherwise finds motions
in which MuJoCo's soft contacts pump energy into the body (one random lift-highest
chain of five spun up and flew 1,031 m high; honest rollouts of 16 random designs of
stand-up and lift-highest gained at most 0.17 J more than their motors' work).

The evaluation episodes are the task's own, run by the worker as for every learner
(:func:`adworker.learners.evaluate_policy`: the same seeds, length, score and falls
rule), so an ``mpc`` score means what the task says. An episode's planning is seeded
from the learner's seed and the episode's first state, so an episode is reproducible
from its seed. The rollouts' physics steps count in the job's ``sim_steps``.

What it does not do: keep a checkpoint (there is no policy to keep: the declaration has
``transfers`` off, so a study asking for ``transfer`` is refused at creation; a warm or
resumed start is ignored, said in ``warm_problem``); report to a pruner while training
(it trains nothing); run on PyBullet (its ``LearnerSpec.simulators`` is MuJoCo alone: a
study asking for it on PyBullet is refused at creation).
"""

from __future__ import annotations

import logging
import math
import zlib
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any, ClassVar

import mujoco
import numpy as np
from pydantic import BaseModel

from adclient.builtin_learners import MPCOptions
from adworker.learners import Learner
from adworker.runner import JobError
from adworker.starts import SCRATCH, Reporting, Start, TrainResult, no_check
from adworker.tasks.base import RobotEnv
from adworker.tasks.mujoco_engine import MujocoSimulator, SimulationDiverged

log = logging.getLogger("adworker")

ENDED_EARLY = -1e12
"""What a rollout's value is offset by when the task ends its episode within it: below
any return a task's reward reaches over a horizon."""
WORK_SLACK = 1.25
"""A rollout is unphysical where the world's mechanical energy rises by more than this
times the work its motors did (the sum of |torque x joint speed| over its physics
steps: the motor meter's energy)..."""
ENERGY_SLACK = 1.0
"""... plus this many joules (soft contacts and joint limits give a little back)."""


class Planner:
    """One env's planner: plans from the env's current state (:meth:`action`), one
    episode at a time (:meth:`begin`)."""

    def __init__(
        self,
        env: RobotEnv,
        options: MPCOptions,
        seed: int,
        check: Callable[[], None] = no_check,
    ) -> None:
        sim = env.sim
        if not isinstance(sim, MujocoSimulator):
            raise JobError(
                f"learner 'mpc' runs on simulator 'mujoco' alone, not {env.simulator!r} "
                "(task.simulator: mujoco)"
            )
        self.env = env
        self.sim: MujocoSimulator = sim
        self.options = options
        self.seed = seed
        self.check = check
        self.joints = env.joint_count
        self.scratch = mujoco.MjData(sim.model)
        """The copy each rollout runs on."""
        horizon, knots = options.horizon, options.knots
        self.knot_times = (
            np.zeros(1) if knots == 1 else np.linspace(0.0, horizon - 1.0, min(knots, horizon))
        )
        self.rollout_steps = 0
        """Control steps simulated by this planner's rollouts, all episodes together."""
        self.unphysical = 0
        """Rollouts ranked last for gaining more energy than their motors put in."""
        self.diverged = 0
        """Rollouts ranked last for diverging (MuJoCo's warning not logged for them)."""
        self.plans = 0
        self._step = 0
        self._nominal = np.zeros((len(self.knot_times), self.joints))
        self._rng = np.random.default_rng(seed)

    # ------------------------------------------------------------------ episodes

    def begin(self) -> None:
        """A new episode, from the env's state now: the nominal plan all zeros (each
        joint's mid-range target), the sampling seeded from the learner's seed and this
        first state (which the episode's seed drew)."""
        first = zlib.crc32(np.ascontiguousarray(self.sim.data.qpos).tobytes())
        # the episode's model (one that draws its physics per episode may rebuild it)
        self.scratch = mujoco.MjData(self.sim.model)
        self._rng = np.random.default_rng([self.seed, first])
        self._nominal = np.zeros_like(self._nominal)
        self._step = 0

    def action(self) -> np.ndarray:
        """The action of this control step: a new plan where one is due."""
        offset = self._step % self.options.replan_every
        if offset == 0:
            self._plan()
        self._step += 1
        return self._actions(self._nominal, offset + 1)[offset].astype(np.float32)

    # ------------------------------------------------------------------ planning

    def _actions(self, knots: np.ndarray, steps: int) -> np.ndarray:
        """The plan's actions for ``steps`` control steps from its start, (steps, joints)."""
        times = np.arange(steps, dtype=float)
        if len(self.knot_times) == 1:
            return np.repeat(knots[:1], steps, axis=0)
        return np.stack(
            [np.interp(times, self.knot_times, knots[:, j]) for j in range(self.joints)], axis=1
        )

    def _shifted(self, knots: np.ndarray, by: int) -> np.ndarray:
        """The plan's knots ``by`` control steps later (its last value held past its end)."""
        if len(self.knot_times) == 1 or by == 0:
            return knots.copy()
        times = self.knot_times + by
        return np.stack(
            [np.interp(times, self.knot_times, knots[:, j]) for j in range(self.joints)], axis=1
        )

    def _plan(self) -> None:
        self.check()
        options = self.options
        left = self.env.episode_steps - self._step
        horizon = max(1, min(options.horizon, left))
        nominal = self._shifted(self._nominal, 0 if self._step == 0 else options.replan_every)
        if options.method == "sampling":
            candidates = self._around(nominal, options.sigma)
            values = self._values(candidates, horizon)
            self._nominal = candidates[int(np.argmax(values))]
        else:
            mean, spread = nominal, np.full(nominal.shape, options.sigma)
            best, best_value = nominal, -math.inf
            for _ in range(options.cem_iterations):
                candidates = self._around(mean, spread)
                values = self._values(candidates, horizon)
                order = np.argsort(-values, kind="stable")
                if values[order[0]] > best_value:
                    best, best_value = candidates[order[0]], float(values[order[0]])
                elites = candidates[order[: options.cem_elites]]
                mean = elites.mean(axis=0)
                spread = np.maximum(elites.std(axis=0), 0.05 * options.sigma)
            self._nominal = best
        self.plans += 1

    def _around(self, mean: np.ndarray, spread: float | np.ndarray) -> np.ndarray:
        """``samples`` plans: ``mean`` itself, then ``mean`` plus Gaussian noise of scale
        ``spread`` on every knot, clipped to the action range."""
        noise = self._rng.standard_normal((self.options.samples - 1, *mean.shape))
        return np.concatenate([mean[None], np.clip(mean + spread * noise, -1.0, 1.0)])

    def _values(self, candidates: np.ndarray, horizon: int) -> np.ndarray:
        return np.array(
            [self._rollout(self._actions(knots, horizon)) for knots in candidates], dtype=float
        )

    def _rollout(self, actions: np.ndarray) -> float:
        """The task's reward summed over ``actions`` from a copy of the world now;
        offset by :data:`ENDED_EARLY` where the task ends the episode within them, -inf
        where the simulation diverges."""
        sim, robot, task = self.sim, self.env.robot, self.env.task
        scratch = self.scratch
        mujoco.mj_copyData(scratch, sim.model, sim.data)
        kept = dict(vars(task))
        total = 0.0
        start = _energy(sim.model, scratch)
        try:
            with _running_on(sim, scratch):
                meter = robot.motor_meter()  # of the copy's motors
                meter.begin_episode()
                for action in actions:
                    robot.act(action)
                    sim.step(meter.sample)
                    self.rollout_steps += 1
                    snapshot = robot.read()
                    gained = _energy(sim.model, scratch) - start
                    if gained > WORK_SLACK * meter.episode_energy[-1] + ENERGY_SLACK:
                        self.unphysical += 1
                        return -math.inf
                    total += float(task.reward(snapshot, task.metric(snapshot)))
                    if task.terminated(snapshot):
                        return total + ENDED_EARLY
        except SimulationDiverged:
            self.diverged += 1
            return -math.inf
        finally:
            vars(task).clear()
            vars(task).update(kept)
        return total if math.isfinite(total) else -math.inf


def _energy(model: Any, data: Any) -> float:
    """The world's mechanical energy (J): gravity's potential and the kinetic energy."""
    mujoco.mj_energyPos(model, data)
    mujoco.mj_energyVel(model, data)
    return float(data.energy[0] + data.energy[1])


@contextmanager
def _running_on(sim: MujocoSimulator, data: Any) -> Iterator[None]:
    """The simulator's world is ``data`` while the block runs (the robot reads and
    commands ``sim.data``), its own again after."""
    own, warn = sim.data, mujoco.get_mju_user_warning()
    sim.data = data
    # a sample that diverges is one of many, ranked last: not a line in the worker's log
    mujoco.set_mju_user_warning(_quiet)
    try:
        yield
    finally:
        sim.data = own
        mujoco.set_mju_user_warning(warn)


def _quiet(message: str) -> None:
    return None


class MPCLearner(Learner):
    """Model-predictive control; see the module docstring. ``train`` builds the planner
    (no training: ``train_steps`` 0) and returns its policy, bound to ``env``: the env
    the worker evaluates on."""

    name: ClassVar[str] = "mpc"
    default_steps: ClassVar[int] = 0

    def __init__(self, options: BaseModel | None = None) -> None:
        super().__init__(options)
        chosen = options if options is not None else MPCOptions()
        if not isinstance(chosen, MPCOptions):
            raise TypeError(f"mpc takes MPCOptions, not {chosen!r}")
        self.settings = chosen
        self.planner: Planner | None = None

    def train(
        self,
        env: RobotEnv,
        *,
        steps: int,
        seed: int,
        check: Callable[[], None] = no_check,
        start: Start = SCRATCH,
        keep_checkpoint: bool = False,
        reporting: Reporting | None = None,
    ) -> TrainResult:
        """``steps`` is not used (nothing is trained); ``keep_checkpoint`` gets none (mpc
        has no state to keep) and ``reporting`` nothing to report."""
        settings = self.settings
        needed = settings.episode_rollout_steps(env.episode_steps)
        if needed > settings.max_rollout_steps:
            raise JobError(
                f"learner 'mpc': an episode of {env.episode_steps} steps plans "
                f"{math.ceil(env.episode_steps / settings.replan_every)} times, "
                f"{settings.plan_steps():,} control steps each: {needed:,} rollout steps, "
                f"more than max_rollout_steps {settings.max_rollout_steps:,} (raise it, or "
                "replan_every, or lower samples or horizon)"
            )
        self.warm_problem = None
        if start is not SCRATCH:
            self.warm_problem = f"the mpc learner has no controller to start from ({start!r})"
            log.warning("%s: planning from scratch", self.warm_problem)
        planner = Planner(env, settings, seed, check)
        self.planner = planner
        sim = planner.sim

        def policy(observation: np.ndarray) -> np.ndarray:
            if sim.data is None:
                raise RuntimeError("mpc's policy acts on the env it was made for, now closed")
            if sim.data.time == 0.0:  # the first step of an episode (reset sets time 0)
                planner.begin()
            return planner.action()

        return TrainResult(
            policy=policy,
            train_steps=0,
            curve=[],
            info={
                "method": settings.method,
                "rollout_steps_per_episode": needed,
                "checkpoint": "none (mpc trains nothing)",
            },
        )
