"""PPO on a :class:`~adworker.gpu.warp_batch.WarpBatch`, one policy per design (issue 59).

Every design of the batch has its own actor and critic (two-layer tanh MLPs, a Gaussian
policy with a learnt log standard deviation per joint), held together as stacked weights
of shape (designs, ...) so a forward pass of all of them is one batched matrix product
over the batch's observations, on the batch's device, with no copy to the host. The
losses of the designs are summed: each design's weights get only its own gradient, and
Adam is per element, so each design trains as if alone (no gradient norm shared across
designs).

The algorithm is the clipped-surrogate PPO of the worker's lean learner
(:mod:`adworker.batch_ppo`) on torch tensors end to end: an unroll of ``unroll`` control
steps of every world, GAE (an episode's end at its time limit is an end: stand-up's
reward is the pose held, nothing after the limit is owed), advantages normalised per
design, ``epochs`` passes of ``minibatches`` minibatches. ``steps`` is the env-step
budget of each design (its worlds' control steps together), as a CPU learner's budget.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch

from adworker.gpu.warp_batch import WarpBatch

MAX_STEPS = 100_000_000
"""The most env steps one design may train (a GPU day at the issue's rate)."""
MAX_HIDDEN = 512


@dataclass(frozen=True)
class GpuPPOOptions:
    steps: int = 1_000_000
    """Env steps per design."""
    unroll: int = 32
    epochs: int = 4
    minibatches: int = 4
    hidden: int = 64
    learning_rate: float = 3e-4
    gamma: float = 0.99
    gae_lambda: float = 0.95
    clip: float = 0.2
    entropy: float = 0.0
    value_coef: float = 0.5
    seed: int = 0

    def problems(self) -> list[str]:
        """What is out of bounds, each naming its option and bound (empty: none)."""
        found = []
        if not 1 <= self.steps <= MAX_STEPS:
            found.append(f"steps must be 1 to {MAX_STEPS} env steps per design")
        if not 1 <= self.unroll <= 4096:
            found.append("unroll must be 1 to 4096 control steps")
        if not 1 <= self.epochs <= 32:
            found.append("epochs must be 1 to 32")
        if not 1 <= self.minibatches <= 256:
            found.append("minibatches must be 1 to 256")
        if not 1 <= self.hidden <= MAX_HIDDEN:
            found.append(f"hidden must be 1 to {MAX_HIDDEN} units")
        return found


def _layer(designs: int, fan_in: int, fan_out: int, gain: float, g: torch.Generator) -> list:
    weight = torch.randn(designs, fan_in, fan_out, generator=g) * (gain / math.sqrt(fan_in))
    return [weight, torch.zeros(designs, 1, fan_out)]


class DesignPolicies(torch.nn.Module):
    """An actor and a critic per design, stacked (see the module docstring)."""

    def __init__(self, designs: int, observations: int, actions: int, hidden: int, seed: int):
        super().__init__()
        g = torch.Generator().manual_seed(seed)
        tensors = (
            _layer(designs, observations, hidden, math.sqrt(2), g)
            + _layer(designs, hidden, hidden, math.sqrt(2), g)
            + _layer(designs, hidden, actions, 0.01, g)
            + _layer(designs, observations, hidden, math.sqrt(2), g)
            + _layer(designs, hidden, hidden, math.sqrt(2), g)
            + _layer(designs, hidden, 1, 1.0, g)
        )
        self.weights = torch.nn.ParameterList(torch.nn.Parameter(t) for t in tensors)
        self.log_std = torch.nn.Parameter(torch.full((designs, 1, actions), -0.5))

    @staticmethod
    def _mlp(x: torch.Tensor, layers: list[torch.nn.Parameter]) -> torch.Tensor:
        w1, b1, w2, b2, w3, b3 = layers
        x = torch.tanh(torch.baddbmm(b1, x, w1))
        x = torch.tanh(torch.baddbmm(b2, x, w2))
        return torch.baddbmm(b3, x, w3)

    def forward(self, observation: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(designs, n, obs) -> the action means (designs, n, actions), values (designs, n)."""
        layers = list(self.weights)
        return self._mlp(observation, layers[:6]), self._mlp(observation, layers[6:])[..., 0]

    def log_prob(self, mean: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        std = self.log_std.exp()
        z = (action - mean) / std
        return (-0.5 * z * z - self.log_std - 0.5 * math.log(2 * math.pi)).sum(-1)


@dataclass
class TrainingResult:
    scores: list[float]
    """Each design's score: the mean over its worlds of a deterministic episode's score
    after training."""
    curve: list[list[float]] = field(default_factory=list)
    """Per training episode, each design's mean episode score (the learning curve)."""
    env_steps: int = 0
    """Env steps trained per design."""


def evaluate(batch: WarpBatch, policies: DesignPolicies | None, seed: int) -> list[float]:
    """Each design's mean score over its worlds of one episode from seed ``seed``, the
    policy's mean action (``None``: uniformly random actions, seeded)."""
    observation = batch.reset(seed=seed)
    g = torch.Generator(device=observation.device).manual_seed(seed)
    shape = (batch.designs, batch.worlds_per_design)
    while True:
        if policies is None:
            actions = (
                torch.rand(batch.nworld, batch.joints, generator=g, device=observation.device) * 2
                - 1
            )
        else:
            with torch.no_grad():
                mean, _ = policies(observation.view(*shape, -1))
            actions = mean.reshape(batch.nworld, -1)
        observation, _, scores = batch.step(actions)
        if scores is not None:
            return scores.view(shape).mean(1).tolist()


def train(batch: WarpBatch, options: GpuPPOOptions) -> tuple[DesignPolicies, TrainingResult]:
    """Train one policy per design of ``batch`` for ``options.steps`` env steps each."""
    problems = options.problems()
    if problems:
        raise ValueError("; ".join(problems))
    device = batch.design_of_world().device
    designs, per = batch.designs, batch.worlds_per_design
    policies = DesignPolicies(
        designs, batch.observation_size, batch.joints, options.hidden, options.seed
    ).to(device)
    optimiser = torch.optim.Adam(policies.parameters(), lr=options.learning_rate, eps=1e-5)
    g = torch.Generator(device=device).manual_seed(options.seed)
    unroll = options.unroll
    rounds = max(1, math.ceil(options.steps / (unroll * per)))
    observation = batch.reset(seed=options.seed).view(designs, per, -1)
    curve: list[list[float]] = []
    size = batch.observation_size
    for _ in range(rounds):
        obs_buf = torch.zeros(unroll, designs, per, size, device=device)
        act_buf = torch.zeros(unroll, designs, per, batch.joints, device=device)
        logp_buf = torch.zeros(unroll, designs, per, device=device)
        value_buf = torch.zeros(unroll + 1, designs, per, device=device)
        reward_buf = torch.zeros(unroll, designs, per, device=device)
        done_buf = torch.zeros(unroll, designs, per, device=device)
        with torch.no_grad():
            for t in range(unroll):
                mean, value = policies(observation)
                noise = torch.randn(mean.shape, generator=g, device=device)
                action = mean + policies.log_std.exp() * noise
                obs_buf[t], act_buf[t], value_buf[t] = observation, action, value
                logp_buf[t] = policies.log_prob(mean, action)
                next_obs, reward, scores = batch.step(action.reshape(batch.nworld, -1))
                reward_buf[t] = reward.view(designs, per)
                if scores is not None:
                    done_buf[t] = 1.0
                    curve.append(scores.view(designs, per).mean(1).tolist())
                observation = next_obs.view(designs, per, -1)
            value_buf[unroll] = policies(observation)[1]
            advantage = torch.zeros_like(reward_buf)
            running = torch.zeros(designs, per, device=device)
            for t in reversed(range(unroll)):
                keep = 1.0 - done_buf[t]
                delta = reward_buf[t] + options.gamma * value_buf[t + 1] * keep - value_buf[t]
                running = delta + options.gamma * options.gae_lambda * keep * running
                advantage[t] = running
            returns = advantage + value_buf[:unroll]

        def flat(x: torch.Tensor) -> torch.Tensor:
            # (unroll, designs, per, ...) -> (designs, unroll * per, ...)
            return x.transpose(0, 1).reshape(designs, unroll * per, *x.shape[3:])

        b_obs, b_act, b_logp = flat(obs_buf), flat(act_buf), flat(logp_buf)
        b_adv, b_ret = flat(advantage), flat(returns)
        b_adv = (b_adv - b_adv.mean(1, keepdim=True)) / (b_adv.std(1, keepdim=True) + 1e-8)
        samples = unroll * per
        chunk = max(1, samples // options.minibatches)
        for _ in range(options.epochs):
            order = torch.randperm(samples, generator=g, device=device)
            for start in range(0, samples, chunk):
                index = order[start : start + chunk]
                mean, value = policies(b_obs[:, index])
                logp = policies.log_prob(mean, b_act[:, index])
                ratio = (logp - b_logp[:, index]).exp()
                adv = b_adv[:, index]
                surrogate = torch.minimum(
                    ratio * adv, torch.clamp(ratio, 1 - options.clip, 1 + options.clip) * adv
                )
                value_loss = (value - b_ret[:, index]).pow(2)
                entropy = policies.log_std.sum(-1).mean()
                loss = (
                    -surrogate.mean(1).sum()
                    + options.value_coef * value_loss.mean(1).sum()
                    - options.entropy * entropy
                )
                optimiser.zero_grad()
                loss.backward()
                optimiser.step()
    final = evaluate(batch, policies, seed=options.seed + 1_000_000)
    return policies, TrainingResult(scores=final, curve=curve, env_steps=rounds * unroll * per)
