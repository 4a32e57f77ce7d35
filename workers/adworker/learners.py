"""Controller learners: what turns a task env into a policy, within a step budget.

``fast`` is a non-RL search over constant joint targets (a design is judged by the
best pose it can hold, found in about a second: :mod:`adworker.constant_search`);
``ddpg`` (the preprint's method), ``td3``, ``sac`` and ``ppo`` train stable-baselines3
agents with small networks, at budgets sized so one evaluation takes about 10 s on one
CPU core per worker process.

A learner gets a built env, a step budget (environment control steps; the task
config's ``train_steps`` overrides the learner's default), a seed and where it starts
(:mod:`adworker.starts`: from scratch, its own paused state, or another design's
controller, or the study's shared controller: PPO alone, :mod:`adworker.modular`), and
returns a deterministic policy plus its training curve. Evaluation is separate (see
:func:`evaluate_policy`) and identical for every learner.

Default budgets (control steps at 10 Hz; an episode is 32 steps), CPU time of one
stand-up evaluation on one core (bench/evaluation.py has the measured figures):

    fast   1,024   32 episodes                                       ~0.5-1 s
    ddpg   2,500   [64, 64] nets, Ornstein-Uhlenbeck exploration     ~7 s
    td3    2,500   as ddpg, twin critics, delayed actor              ~7 s
    sac    2,000   [64, 64] nets, entropy weight 0.01                ~8 s
    ppo   12,288   [64, 64] nets, rollouts of 512, 10 epochs         ~8 s

Off-policy learners update once per step (batch 64, gamma 0.95: the horizon of a
pose-holding task is short). Exploration must be correlated in time: a new random
target every 0.1 s only shakes the joints, while Ornstein-Uhlenbeck noise holds a
direction long enough to find a pose.
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
from pydantic import BaseModel

from adclient.builtin_learners import (
    OffPolicyOptions,
    PPOOptions,
    SACOptions,
    StableBaselinesOptions,
    TD3Options,
)
from adclient.devices import LEARNER_DEVICE_VARIABLE
from adworker import checkpoints
from adworker.runner import Pruned
from adworker.starts import (
    SCRATCH,
    Policy,
    Reporting,
    Resume,
    Shared,
    Start,
    TrainResult,
    Warm,
    from_attributes,
    no_check,
)
from adworker.task_metrics import checked_task_metrics
from adworker.tasks.base import RobotEnv

log = logging.getLogger("adworker")


WarmStart = Warm
"""Deprecated name of :class:`adworker.starts.Warm` (a plugin of the attribute interface
may import it), kept for one release."""


@dataclass
class EpisodeResult:
    seed: int
    score: float
    episode_return: float
    metric: list[float]
    task_metrics: dict[str, float] = field(default_factory=dict)
    """The task's own metrics of the episode (:mod:`adworker.task_metrics`), checked."""


def evaluate_policy(
    env: RobotEnv, policy: Policy, seeds: list[int], check: Callable[[], None] = no_check
) -> list[EpisodeResult]:
    """Run one deterministic episode per seed; the score is the task's episode score,
    and an env that offers ``task_metrics()`` is asked for its task's own metrics once
    each episode has ended (ValueError naming one that is not allowed).

    ``check`` runs before each episode and may raise to cancel the evaluation.
    """
    task_metrics = getattr(env, "task_metrics", None)
    results = []
    for seed in seeds:
        check()
        observation, _ = env.reset(seed=seed)
        total = 0.0
        truncated = terminated = False
        while not (terminated or truncated):
            observation, reward, terminated, truncated, _ = env.step(policy(observation))
            total += reward
        own = checked_task_metrics(task_metrics()) if callable(task_metrics) else {}
        results.append(EpisodeResult(seed, env.record.score(), total, list(env.record.metric), own))
    return results


class Learner:
    """What a learner plugin's factory returns (given the learner's options model
    instance, or None when it declares none): ``train`` within a step budget."""

    name: ClassVar[str]
    default_steps: ClassVar[int]

    def __init__(self, options: BaseModel | None = None) -> None:
        self.options = options
        self.warm_problem: str | None = None
        """Why the last ``train``'s ``Warm`` start was not used (it trained from
        scratch), if so."""

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
        """Train within ``steps`` env steps from ``start``; ``check`` is called often and
        may raise. ``keep_checkpoint``: return the final state as
        ``TrainResult.checkpoint`` (a study with ``task.transfer``, so later designs can
        start from it). ``reporting``: a study with a pruner; a learner that reports
        scores its policy with it as it trains."""
        raise NotImplementedError


class StableBaselinesLearner(Learner):
    """A stable-baselines3 agent with small networks; see the subclasses for budgets.

    Its constructor arguments are its options model's (``options_model``, in
    :mod:`adclient.builtin_learners`: the learner's own settings as defaults, a job's
    ``task.options.learner_kwargs`` replacing any of them within their bounds), and
    nothing else: no option reaches SB3 that the model does not declare.
    """

    algorithm: ClassVar[str]
    options_model: ClassVar[type[StableBaselinesOptions]]

    def __init__(self, options: BaseModel | None = None) -> None:
        super().__init__(options)
        chosen = options if options is not None else self.options_model()
        if not isinstance(chosen, self.options_model):
            raise TypeError(f"{self.name} takes {self.options_model.__name__}, not {chosen!r}")
        self.settings = chosen

    def make_model(
        self,
        env: Any,
        *,
        steps: int,
        seed: int,
        policy: Any = "MlpPolicy",
        policy_kwargs: dict[str, Any] | None = None,
    ) -> Any:
        """A fresh model of this learner's settings for ``env``: an MLP of ``net_arch``
        unless ``policy`` and its ``policy_kwargs`` are given (the modular policy)."""
        env = self.training_env(env)
        try:
            return self._model_on(env, steps=steps, seed=seed, policy=policy, kwargs=policy_kwargs)
        except BaseException:
            release_batch(env, None)
            raise

    def training_env(self, env: Any) -> Any:
        """The env the model trains on, given the job's (PPO: maybe a batch of it)."""
        return env

    def _model_on(
        self, env: Any, *, steps: int, seed: int, policy: Any, kwargs: dict[str, Any] | None
    ) -> Any:
        import stable_baselines3

        policy_kwargs = kwargs
        kwargs = self.settings.hyperparameters()
        if policy_kwargs is not None:
            kwargs["policy_kwargs"] = policy_kwargs
        if "buffer_size" in kwargs:
            kwargs["buffer_size"] = max(int(kwargs["buffer_size"]), steps, 1000)
        if "learning_starts" in kwargs:
            kwargs["learning_starts"] = min(int(kwargs["learning_starts"]), max(steps // 4, 1))
        if "n_steps" in kwargs and steps < 2 * int(kwargs["n_steps"]):
            kwargs["n_steps"] = max(32, steps // 2)
            kwargs["batch_size"] = min(int(kwargs.get("batch_size", 64)), kwargs["n_steps"])
        worlds = int(getattr(env, "num_envs", 1))
        if "n_steps" in kwargs and worlds > 1:
            # n_steps is the rollout of all worlds together (SB3's is per world): the same
            # samples per update, so a batch trains as one env on the same budget does
            kwargs["n_steps"] = max(1, math.ceil(int(kwargs["n_steps"]) / worlds))
            rollout = kwargs["n_steps"] * worlds
            kwargs["batch_size"] = min(int(kwargs.get("batch_size", 64)), rollout)
        noise = kwargs.pop("action_noise", None)
        if noise is not None:
            kwargs["action_noise"] = _action_noise(env, **noise)
        cls = getattr(stable_baselines3, self.algorithm)
        model = cls(policy, env, seed=seed, device=learner_device(), verbose=0, **kwargs)
        return _without_log_folder(model)

    def train(
        self,
        env: RobotEnv,
        *,
        steps: int,
        seed: int,
        check: Callable[[], None] = no_check,
        start: Start | None = None,
        keep_checkpoint: bool | None = None,
        reporting: Reporting | None = None,
    ) -> TrainResult:
        import torch
        from stable_baselines3.common.callbacks import BaseCallback

        start, keep_checkpoint, reporting = from_attributes(self, start, keep_checkpoint, reporting)

        torch.set_num_threads(1)
        curve: list[dict[str, float]] = []
        self.warm_problem = None

        class EpisodeScores(BaseCallback):
            def _on_step(self) -> bool:
                # once every 64 steps, however many worlds each call steps
                if self.num_timesteps % 64 < self.training_env.num_envs:
                    check()
                if reporting is not None and reporting.due <= self.num_timesteps < steps:
                    # The current deterministic policy, scored as the final one will be.
                    value = reporting.evaluate(_deterministic(self.model))
                    reporting.send(self.num_timesteps, value)
                for info in self.locals.get("infos", []):
                    if "score" in info:
                        curve.append(
                            {"steps": float(self.num_timesteps), "score": float(info["score"])}
                        )
                return True

        resuming = isinstance(start, Resume)
        warm = self._warm_model(env, start, seed=seed) if isinstance(start, Warm) else None
        shared_start = None
        if isinstance(start, Shared):
            model, shared_start = self._shared_model(env, start, steps=steps, seed=seed)
            # the start's steps, but the from-scratch budget for a version that did not load
            refused = start.weights is not None and self.warm_problem is not None
            steps = start.steps if shared_start is not None and not refused else steps
        elif isinstance(start, Resume):
            model = self.load_checkpoint(env, start.checkpoint, steps=steps, seed=seed)
            if reporting is not None:
                reporting.resume_at(int(model.num_timesteps))
        elif isinstance(start, Warm) and warm is not None:
            model, steps = warm, start.steps
        else:
            model = self.make_model(env, steps=steps, seed=seed)
        resumed_at = int(model.num_timesteps)
        try:
            # a Shared start whose version loaded (not the initial weights)
            version = start if isinstance(start, Shared) and start.weights is not None else None
            if version is not None and self.warm_problem is None:
                if reporting is not None:
                    # Screening: the study's shared controller scored on this design
                    # before any training, reported at step 0 for its pruner to judge.
                    reporting.send(0, reporting.evaluate(_deterministic(model)))
                if version.carries == "critic":
                    from adworker.modular import fresh_actor

                    fresh_actor(model, version.seed)
            if steps > resumed_at:
                model.learn(
                    total_timesteps=steps - resumed_at,
                    callback=EpisodeScores(),
                    reset_num_timesteps=not resuming,
                    progress_bar=False,
                )
        except Pruned as stopped:
            if stopped.pause:
                stopped.checkpoint = self.checkpoint(model)
            raise
        finally:
            release_batch(model, env)
        result = TrainResult(
            policy=_deterministic(model),
            train_steps=int(model.num_timesteps),
            curve=curve,
            info={"algorithm": self.algorithm},
            checkpoint=self.checkpoint(model) if keep_checkpoint else None,
            warm_started=warm is not None,
        )
        if isinstance(start, Shared) and shared_start is not None:
            from adworker.modular import shared_weights_of

            result.shared, result.shared_start = shared_weights_of(model), shared_start
            result.info["policy"] = "modular"
            result.warm_started = self.warm_problem is None and start.weights is not None
        return result

    def _shared_model(
        self, env: Any, start: Shared, *, steps: int, seed: int
    ) -> tuple[Any, dict[str, np.ndarray] | None]:
        """The model of a ``Shared`` start and the weights it starts from; a learner
        without a modular policy (all but PPO) says so in ``warm_problem`` and gives a
        fresh model of its own to train from scratch at ``steps`` (its start None)."""
        self.warm_problem = f"the {self.name} learner has no shared controller (ppo has)"
        log.warning("shared start refused (%s): training from scratch", self.warm_problem)
        return self.make_model(env, steps=steps, seed=seed), None

    def _warm_model(self, env: Any, start: Warm, *, seed: int) -> Any:
        """The model of a ``Warm`` start on this design's env, its step count at zero and
        its replay buffer kept (an off-policy learner updates from the first step);
        None, with the reason in ``warm_problem`` and logged, when it does not fit
        (another observation or action space, a corrupt file, one that is not weights
        alone): the design trains from scratch."""
        try:
            model = self.load_checkpoint(env, start.checkpoint, steps=start.steps, seed=seed)
        except Exception as error:
            self.warm_problem = f"{type(error).__name__}: {error}"
            log.warning("warm start refused (%s): training from scratch", self.warm_problem)
            return None
        model.num_timesteps = 0
        if hasattr(model, "learning_starts"):
            model.learning_starts = 0
        model.set_random_seed(seed)
        return model

    def checkpoint(self, model: Any) -> bytes:
        """The model's weights, optimisers and step count and, for an off-policy learner,
        its replay buffer, as data only (:mod:`adworker.checkpoints`): without the buffer
        a resumed SAC/TD3/DDPG would update at once from a nearly empty one
        (``learning_starts`` is long past), a different algorithm from the one that
        would have trained on. The buffer holds at most the budget's transitions, about
        0.2 kB each deflated for these robots (4 MB at 20,000 steps, within the
        server's artifact limit)."""
        return checkpoints.save(model)

    def load_checkpoint(self, env: Any, checkpoint: bytes, *, steps: int, seed: int) -> Any:
        """A model built here for ``env`` from this learner's own settings (as
        :meth:`make_model` for ``steps``), filled with a :meth:`checkpoint`'s state;
        ``checkpoints.CheckpointError`` when it does not fit. Nothing in the file is
        unpickled: it cannot choose what is built. The env is reset at the next
        ``learn``."""
        model = self.make_model(env, steps=steps, seed=seed)
        try:
            checkpoints.load_into(model, checkpoint)
        except BaseException:
            release_batch(model, env)
            raise
        # Seeded from the step it resumes at: not the exploration it started with.
        model.set_random_seed(seed + int(model.num_timesteps))
        return model


def release_batch(model: Any, env: Any) -> None:
    """After training on a batch of worlds (:mod:`adworker.batched`; ``model`` the SB3
    model trained on it, or the batch itself): close the worlds it built and count their
    physics steps in ``env``'s (its world 0), which the job reports as its
    ``sim_steps``."""
    from adworker.batched import BatchedEnv

    batch = model.get_env() if hasattr(model, "get_env") else model
    if isinstance(batch, BatchedEnv):
        steps = batch.close_copies()
        if env is not None and batch.worlds[0] is env:
            env.sim.physics_steps += steps


def _without_log_folder(model: Any) -> Any:
    """``model`` with a logger that writes nothing: without one, SB3's ``learn`` makes
    its default, which creates a folder ``SB3-<date-time>`` in the system temporary
    folder and leaves it there, one per training (no study may ask for a
    ``tensorboard_log``)."""
    from stable_baselines3.common.logger import Logger

    model.set_logger(Logger(folder=None, output_formats=[]))
    return model


def learner_device() -> str:
    """The torch device networks train on: ``adworker --learner-device``, which sets it
    for every job process (stable-baselines3 itself would fall back to cpu silently)."""
    return os.environ.get(LEARNER_DEVICE_VARIABLE, "cpu")


def _deterministic(model: Any) -> Policy:
    def policy(observation: np.ndarray) -> np.ndarray:
        action, _ = model.predict(observation, deterministic=True)
        return np.asarray(action, dtype=np.float32)

    return policy


def _action_noise(env: RobotEnv, kind: str = "normal", sigma: float = 0.3, **kwargs: Any) -> Any:
    from stable_baselines3.common.noise import NormalActionNoise, OrnsteinUhlenbeckActionNoise

    joints = env.joint_count
    mean, scale = np.zeros(joints), sigma * np.ones(joints)
    if kind == "ou":
        return OrnsteinUhlenbeckActionNoise(mean=mean, sigma=scale, **kwargs)
    return NormalActionNoise(mean=mean, sigma=scale)


class DDPGLearner(StableBaselinesLearner):
    """Deep deterministic policy gradient, as in the preprint."""

    name: ClassVar[str] = "ddpg"
    algorithm: ClassVar[str] = "DDPG"
    options_model: ClassVar[type[StableBaselinesOptions]] = OffPolicyOptions
    default_steps: ClassVar[int] = OffPolicyOptions.default_steps


class TD3Learner(StableBaselinesLearner):
    name: ClassVar[str] = "td3"
    algorithm: ClassVar[str] = "TD3"
    options_model: ClassVar[type[StableBaselinesOptions]] = TD3Options
    default_steps: ClassVar[int] = TD3Options.default_steps


class SACLearner(StableBaselinesLearner):
    name: ClassVar[str] = "sac"
    algorithm: ClassVar[str] = "SAC"
    options_model: ClassVar[type[StableBaselinesOptions]] = SACOptions
    default_steps: ClassVar[int] = SACOptions.default_steps


class PPOLearner(StableBaselinesLearner):
    name: ClassVar[str] = "ppo"
    algorithm: ClassVar[str] = "PPO"
    options_model: ClassVar[type[StableBaselinesOptions]] = PPOOptions
    default_steps: ClassVar[int] = PPOOptions.default_steps

    def training_env(self, env: Any) -> Any:
        """With ``n_envs`` above 1, a batch of that many worlds of ``env``'s design
        (:mod:`adworker.batched`; ``env`` its world 0), whose other worlds
        :func:`release_batch` closes after training; else ``env``."""
        from stable_baselines3.common.vec_env import VecEnv

        worlds = self.settings.n_envs if isinstance(self.settings, PPOOptions) else 1
        if worlds > 1 and not isinstance(env, VecEnv):
            from adworker.batched import BatchedEnv

            return BatchedEnv.of(env, worlds)
        return env

    def _shared_model(
        self, env: Any, start: Shared, *, steps: int, seed: int
    ) -> tuple[Any, dict[str, np.ndarray] | None]:
        """The modular policy of this design (:mod:`adworker.modular`) loaded with the
        start's weights, or with the study's initial ones for ``start.seed`` when it
        has none or they do not load (the reason in ``warm_problem``, logged): the
        model and the weights it starts from, to train ``start.steps``."""
        from adworker import modular
        from adworker.shared_weights import SharedWeightsError

        model = self.make_model(
            env,
            steps=start.steps,
            seed=seed,
            policy=modular.ModularPolicy,
            policy_kwargs=modular.policy_kwargs(env),
        )
        weights = start.weights
        if weights is not None:
            try:
                modular.load_shared(model, weights)
            except SharedWeightsError as error:
                self.warm_problem = f"shared weights of version {start.version}: {error}"
                log.warning("%s: starting from the initial weights", self.warm_problem)
                weights = None
        if weights is None:
            weights = modular.initial_weights(model, start.seed)
            modular.load_shared(model, weights)
        return model, modular.shared_weights_of(model)
