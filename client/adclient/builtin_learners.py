"""The built-in learners, declared as any plugin declares its own (entry points in
pyproject.toml). Their code lives in adworker.learners; only the worker imports it.

Each stable-baselines3 learner's options model is the whitelist of what a study's
``task.options.learner_kwargs`` may set: every option bounded, with the learner's own
value as its default (the one place it lives: adworker builds the model from it), and
:meth:`StableBaselinesOptions.budget_problems` bounding what they cost together for a
job's steps (gradient updates, the samples they pass through the networks, the
networks' size). Anything else (``policy_kwargs``, ``tensorboard_log``, ``device``,
``verbose``...) is refused by name."""

from __future__ import annotations

import math
from itertools import pairwise
from typing import Annotated, Any, ClassVar, Literal, NamedTuple

from pydantic import Field

from adclient.plugins import LearnerOptions, LearnerSpec

MAX_UPDATES = 10_000_000
"""The most gradient updates a job's options may ask for: one per step at the largest
``train_steps``."""
MAX_GRADIENT_SAMPLES = 1_000_000_000
"""The most samples those updates may pass through the networks (updates x batch size)."""
MAX_NET_WEIGHTS = 65_536
"""The most weights between a network's hidden layers (``[256, 256]``)."""

MAX_BATCH_WORLDS = 32
"""The most worlds PPO's ``n_envs`` may train on together: each is a whole simulator (a
PyBullet client holds about 28 MB), so 32 stay well within a job's default memory
(``--job-memory-mb`` 2048); 8 to 32 measured alike on one core (bench/engines.py)."""

Width = Annotated[int, Field(ge=1, le=256)]


class Work(NamedTuple):
    """What a job's training costs: gradient updates and the samples they pass through
    the networks, each with how it was counted."""

    updates: int
    samples: int
    updates_counted: str
    samples_counted: str


class ActionNoise(LearnerOptions):
    """Exploration noise of an off-policy learner: Gaussian (``normal``) or
    Ornstein-Uhlenbeck (``ou``, correlated in time), per joint."""

    kind: Literal["normal", "ou"] = "normal"
    sigma: float = Field(default=0.3, ge=0.0, le=10.0, description="Its scale")
    theta: float | None = Field(
        default=None, gt=0.0, le=100.0, description="ou only: its pull back to 0 (SB3: 0.15)"
    )
    dt: float | None = Field(
        default=None, gt=0.0, le=10.0, description="ou only: its time step (SB3: 0.01)"
    )


class StableBaselinesOptions(LearnerOptions):
    """What every stable-baselines3 learner takes; see the subclasses."""

    default_steps: ClassVar[int]
    """The learner's step budget where the study sets no ``train_steps``."""

    learning_rate: float = Field(default=1e-3, gt=0.0, le=1.0)
    gamma: float = Field(default=0.95, ge=0.0, le=1.0, description="Discount factor")
    net_arch: list[Width] = Field(
        default=[64, 64],
        min_length=1,
        max_length=4,
        description="Hidden layers' widths of the actor's and the critic's networks",
    )

    def hyperparameters(self) -> dict[str, Any]:
        """The model's constructor arguments (the networks as ``policy_kwargs``, the
        noise as its mapping)."""
        kwargs = self.model_dump(exclude={"net_arch"}, exclude_none=True)
        kwargs["policy_kwargs"] = {"net_arch": list(self.net_arch)}
        return kwargs

    def work(self, steps: int) -> Work:
        """The training of a job of ``steps`` steps."""
        raise NotImplementedError

    def budget_problems(self, steps: int | None) -> list[str]:
        steps = self.default_steps if steps is None else steps
        problems = []
        weights = sum(a * b for a, b in pairwise(self.net_arch))
        if weights > MAX_NET_WEIGHTS:
            problems.append(
                f"net_arch {self.net_arch} has {weights:,} weights between its hidden "
                f"layers, more than the limit of {MAX_NET_WEIGHTS:,}"
            )
        work = self.work(steps)
        if work.updates > MAX_UPDATES:
            problems.append(
                f"{work.updates:,} gradient updates ({work.updates_counted}) exceed the "
                f"limit of {MAX_UPDATES:,}"
            )
        elif work.samples > MAX_GRADIENT_SAMPLES:
            problems.append(
                f"{work.samples:,} gradient samples ({work.samples_counted}) exceed the "
                f"limit of {MAX_GRADIENT_SAMPLES:,}"
            )
        return problems


class OffPolicyOptions(StableBaselinesOptions):
    """DDPG's options, and what TD3 and SAC share with it."""

    default_steps: ClassVar[int] = 2500

    buffer_size: int = Field(
        default=1000,
        ge=1,
        le=1_000_000,
        description="Replay buffer transitions (at least the job's steps: it keeps them all)",
    )
    learning_starts: int = Field(
        default=256, ge=0, le=1_000_000, description="Steps before the first update"
    )
    batch_size: int = Field(default=64, ge=1, le=1024)
    tau: float = Field(default=0.02, gt=0.0, le=1.0, description="Target networks' update rate")
    train_freq: int = Field(default=1, ge=1, le=100_000, description="Steps between updates")
    gradient_steps: int = Field(default=1, ge=1, le=1000, description="Updates each time")
    action_noise: ActionNoise | None = Field(
        default=ActionNoise(kind="ou", sigma=0.5, dt=0.1), description="Exploration noise"
    )

    def work(self, steps: int) -> Work:
        updates = math.ceil(steps / self.train_freq) * self.gradient_steps
        counted = (
            f"{steps:,} steps / train_freq {self.train_freq} x gradient_steps {self.gradient_steps}"
        )
        return Work(
            updates, updates * self.batch_size, counted, f"{counted} x batch_size {self.batch_size}"
        )


class TD3Options(OffPolicyOptions):
    policy_delay: int = Field(
        default=2, ge=1, le=1000, description="Critic updates per actor update"
    )
    target_policy_noise: float = Field(default=0.2, ge=0.0, le=10.0)
    target_noise_clip: float = Field(default=0.5, ge=0.0, le=10.0)


class SACOptions(OffPolicyOptions):
    default_steps: ClassVar[int] = 2000

    action_noise: ActionNoise | None = Field(default=None, description="Exploration noise")
    # A fixed, small entropy weight: the automatic one keeps the policy too random to
    # settle on a pose within this budget.
    ent_coef: Annotated[float, Field(gt=0.0, le=10.0)] | Literal["auto"] = Field(
        default=0.01, description="Entropy weight, or auto (learned)"
    )
    target_update_interval: int = Field(default=1, ge=1, le=100_000)


class PPOOptions(StableBaselinesOptions):
    """Short rollouts and large minibatches: 24 updates of 10 epochs within the budget."""

    default_steps: ClassVar[int] = 12288

    n_steps: int = Field(default=512, ge=8, le=16_384, description="Steps of a rollout")
    batch_size: int = Field(default=128, ge=2, le=16_384, description="Minibatch size")
    n_epochs: int = Field(default=10, ge=1, le=100, description="Passes over each rollout")
    gae_lambda: float = Field(default=0.9, ge=0.0, le=1.0)
    clip_range: float = Field(default=0.2, gt=0.0, le=10.0)
    ent_coef: float = Field(default=0.0, ge=0.0, le=10.0, description="Entropy weight")
    vf_coef: float = Field(default=0.5, ge=0.0, le=100.0, description="Value loss weight")
    max_grad_norm: float = Field(default=0.5, gt=0.0, le=1000.0)
    target_kl: float | None = Field(default=None, gt=0.0, le=100.0)
    n_envs: int = Field(
        default=1,
        ge=1,
        le=MAX_BATCH_WORLDS,
        description="Worlds of the design trained on together (adworker.batched), the "
        "policy evaluated once for all of them; n_steps is the rollout of all together",
    )

    def hyperparameters(self) -> dict[str, Any]:
        kwargs = super().hyperparameters()
        del kwargs["n_envs"]  # the worker's batch of worlds, not an argument of SB3's PPO
        return kwargs

    def work(self, steps: int) -> Work:
        passes = math.ceil(steps / self.n_steps) * self.n_epochs
        minibatches = math.ceil(self.n_steps / self.batch_size)
        counted = f"{steps:,} steps / n_steps {self.n_steps} x n_epochs {self.n_epochs}"
        return Work(
            passes * minibatches,
            passes * self.n_steps,
            f"{counted} x {minibatches} minibatches of batch_size {self.batch_size}",
            f"{counted} x n_steps {self.n_steps}",
        )


class BatchPPOOptions(StableBaselinesOptions):
    """``ppo-batch`` (adworker.batch_ppo): a PPO of the worker's own that trains on a batch
    of ``n_envs`` worlds, as batched RL sets it (Brax, MuJoCo Playground): a rollout of
    ``n_envs`` x ``unroll`` samples, cut into ``n_minibatches``, ``n_epochs`` passes over
    it. The defaults: a rollout of 512 (as ``ppo``'s), 4 minibatches of 128 and 4 epochs,
    16 updates per rollout against ``ppo``'s 40 (bench/engines.py ``--learn`` measured
    what each learns at the same steps)."""

    default_steps: ClassVar[int] = PPOOptions.default_steps

    n_envs: int = Field(
        default=16, ge=1, le=MAX_BATCH_WORLDS, description="Worlds trained on together"
    )
    unroll: int = Field(default=32, ge=1, le=4096, description="Steps of each world a rollout")
    n_minibatches: int = Field(default=4, ge=1, le=1024, description="Minibatches a rollout")
    n_epochs: int = Field(default=4, ge=1, le=100, description="Passes over each rollout")
    gae_lambda: float = Field(default=0.9, ge=0.0, le=1.0)
    clip_range: float = Field(default=0.2, gt=0.0, le=10.0)
    ent_coef: float = Field(default=0.0, ge=0.0, le=10.0, description="Entropy weight")
    vf_coef: float = Field(default=0.5, ge=0.0, le=100.0, description="Value loss weight")
    max_grad_norm: float = Field(default=0.5, gt=0.0, le=1000.0)
    log_std_init: float = Field(
        default=0.0, ge=-10.0, le=2.0, description="The policy's initial log standard deviation"
    )

    @property
    def rollout(self) -> int:
        """Samples of one rollout, all worlds together."""
        return self.n_envs * self.unroll

    def work(self, steps: int) -> Work:
        rollouts = math.ceil(steps / self.rollout)
        minibatches = min(self.n_minibatches, self.rollout)
        counted = (
            f"{steps:,} steps / (n_envs {self.n_envs} x unroll {self.unroll}) x n_epochs "
            f"{self.n_epochs}"
        )
        passes = rollouts * self.n_epochs
        return Work(
            passes * minibatches,
            passes * self.rollout,
            f"{counted} x n_minibatches {minibatches}",
            f"{counted} x {self.rollout} samples",
        )


FAST = LearnerSpec(
    name="fast",
    description="A search over constant joint targets: the best pose the design can reach "
    "and hold, in about a second (no RL).",
    factory="adworker.constant_search:ConstantTargetSearch",
)
DDPG = LearnerSpec(
    name="ddpg",
    description="stable-baselines3 DDPG (the preprint's learner), [64, 64] networks, "
    "Ornstein-Uhlenbeck exploration.",
    factory="adworker.learners:DDPGLearner",
    options=OffPolicyOptions,
    transfers=True,
)
TD3 = LearnerSpec(
    name="td3",
    description="stable-baselines3 TD3, settings as ddpg.",
    factory="adworker.learners:TD3Learner",
    options=TD3Options,
    transfers=True,
)
SAC = LearnerSpec(
    name="sac",
    description="stable-baselines3 SAC, [64, 64] networks, entropy weight 0.01.",
    factory="adworker.learners:SACLearner",
    options=SACOptions,
    transfers=True,
)
PPO = LearnerSpec(
    name="ppo",
    description="stable-baselines3 PPO, [64, 64] networks, rollouts of 512.",
    factory="adworker.learners:PPOLearner",
    options=PPOOptions,
    transfers=True,
    shares=True,
)
PPO_BATCH = LearnerSpec(
    name="ppo-batch",
    description="PPO of the worker's own on a batch of worlds (16 by default), the policy "
    "evaluated once per batch step, [64, 64] networks, rollouts of 16 x 32.",
    factory="adworker.batch_ppo:BatchPPOLearner",
    options=BatchPPOOptions,
    transfers=True,
)


# ---------------------------------------------------------------- mpc (issue 59)

MAX_MPC_ROLLOUT_STEPS = 1_000_000
"""The most control steps ``mpc``'s planner may simulate in its rollouts for one
evaluation episode (``max_rollout_steps``): about 100 s of one core on a small design."""


class MPCOptions(LearnerOptions):
    """Sampling-based model-predictive control from the current state (adworker.mpc): no
    training; each plan samples ``samples`` action sequences of ``horizon`` control steps
    around the nominal plan, rolls them out on copies of the world and keeps the best.
    What a plan costs is ``samples x horizon`` control steps (``x cem_iterations`` for
    CEM); an episode plans once every ``replan_every`` of its steps, within
    ``max_rollout_steps``."""

    method: Literal["sampling", "cem"] = Field(
        default="sampling",
        description="sampling: predictive sampling (the best sample is the new plan); cem: "
        "the cross-entropy method (cem_iterations refits to the elite samples)",
    )
    samples: int = Field(default=16, ge=2, le=256, description="Action sequences per plan")
    horizon: int = Field(default=8, ge=1, le=64, description="Control steps each one looks ahead")
    knots: int = Field(
        default=3,
        ge=1,
        le=16,
        description="Knots of a plan (linear between them, over the horizon)",
    )
    sigma: float = Field(
        default=0.3, gt=0.0, le=2.0, description="Sampling noise on the knots (actions in [-1, 1])"
    )
    replan_every: int = Field(default=1, ge=1, le=64, description="Control steps between plans")
    cem_iterations: int = Field(default=3, ge=1, le=16, description="cem only: refits per plan")
    cem_elites: int = Field(default=4, ge=1, le=64, description="cem only: samples refitted to")
    max_rollout_steps: int = Field(
        default=65_536,
        ge=1,
        le=MAX_MPC_ROLLOUT_STEPS,
        description="The most control steps the planner simulates for one evaluation "
        "episode, all its plans together (the job fails naming it where the episode's "
        "plans need more)",
    )

    def plan_steps(self) -> int:
        """Control steps one plan simulates."""
        iterations = self.cem_iterations if self.method == "cem" else 1
        return self.samples * self.horizon * iterations

    def episode_rollout_steps(self, episode_steps: int) -> int:
        """Control steps the plans of an episode of ``episode_steps`` steps simulate."""
        return math.ceil(episode_steps / self.replan_every) * self.plan_steps()

    def budget_problems(self, steps: int | None) -> list[str]:
        """``steps`` is not used: mpc trains nothing (its cost is its evaluation's)."""
        problems = []
        if self.method == "cem" and self.cem_elites >= self.samples:
            problems.append(
                f"cem_elites {self.cem_elites} must be fewer than samples {self.samples}"
            )
        if self.plan_steps() > self.max_rollout_steps:
            problems.append(
                f"one plan simulates {self.plan_steps():,} control steps (samples x horizon"
                f"{' x cem_iterations' if self.method == 'cem' else ''}), more than "
                f"max_rollout_steps {self.max_rollout_steps:,} (at most "
                f"{MAX_MPC_ROLLOUT_STEPS:,})"
            )
        return problems


MPC = LearnerSpec(
    name="mpc",
    description="Sampling-based model-predictive control on MuJoCo (predictive sampling or "
    "CEM from the current state): no training, a design judged in seconds.",
    factory="adworker.mpc:MPCLearner",
    options=MPCOptions,
    simulators=("mujoco",),
)
