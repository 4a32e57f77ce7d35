"""The built-in learners, declared as any plugin declares its own (entry points in
pyproject.toml). Their code lives in adworker.learners; only the worker imports it."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict

from adclient.plugins import LearnerSpec


class StableBaselinesOptions(BaseModel):
    """Overrides of the stable-baselines3 algorithm's constructor arguments (any of them,
    e.g. ``learning_rate``), and ``action_noise`` as ``{kind: normal | ou, sigma: s}``."""

    model_config = ConfigDict(extra="allow", allow_inf_nan=False)


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
    options=StableBaselinesOptions,
    transfers=True,
)
TD3 = LearnerSpec(
    name="td3",
    description="stable-baselines3 TD3, settings as ddpg.",
    factory="adworker.learners:TD3Learner",
    options=StableBaselinesOptions,
    transfers=True,
)
SAC = LearnerSpec(
    name="sac",
    description="stable-baselines3 SAC, [64, 64] networks, entropy weight 0.01.",
    factory="adworker.learners:SACLearner",
    options=StableBaselinesOptions,
    transfers=True,
)
PPO = LearnerSpec(
    name="ppo",
    description="stable-baselines3 PPO, [64, 64] networks, rollouts of 512.",
    factory="adworker.learners:PPOLearner",
    options=StableBaselinesOptions,
    transfers=True,
    shares=True,
)
