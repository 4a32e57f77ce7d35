"""``ppo-batch`` (issue 59): a lean PPO of the worker's own that trains on a batch of
worlds (:mod:`adworker.batched`), no stable-baselines3 object in its loop.

Why not SB3's PPO on the batch (the ``ppo`` learner's ``n_envs``): its update, 10
epochs of 128-sample minibatches over every 512 samples, is half its CPU on a batch,
and its rollout pays torch's per-call cost once per batch step (bench/RESULTS.md,
"Engines"). Here:

- the rollout: the policy evaluated once per batch step on the whole batch of
  observations, in NumPy (two small matrix products: no torch call per step), its
  weights copied from torch after each update; the samples in arrays allocated once
  (``unroll`` x ``n_envs``);
- GAE over the rollout, vectorised across worlds (one loop over its ``unroll`` steps),
  a time limit's end bootstrapped from the value of its terminal observation (as SB3
  does);
- the update by hand on torch: the clipped surrogate, the value loss, the Gaussian
  log-probability of a state-independent standard deviation, advantages normalised per
  minibatch, gradients clipped by norm, Adam (eps 1e-5, SB3's PPO's);
- its settings as batched RL sets them (Brax, MuJoCo Playground): a rollout of
  ``n_envs`` x ``unroll`` samples, minibatches sized to it (``n_minibatches``), few
  epochs. The networks are SB3's ``MlpPolicy``'s (separate actor and critic of
  ``net_arch``, tanh, orthogonal initialisation), so one update is the same work.

The contracts the other learners keep: the checkpoint (:func:`save`, arrays read with
``np.load(allow_pickle=False)`` after :mod:`adworker.npy_archives`' checks), a
``Resume`` and a ``Warm`` start from it, a pruner's reports and a pause's checkpoint,
the curve (every world's ended training episodes, in steps of all worlds together).
A ``Shared`` start (the study's shared controller) is ``ppo``'s alone: a study asking it
of ``ppo-batch`` is refused at creation (its spec does not declare ``shares``).

A budget of ``steps`` trains ``ceil(steps / n_envs)`` steps of every world: at most
``n_envs - 1`` more than asked, reported as ``train_steps``.
"""

from __future__ import annotations

import io
import logging
import math
import zipfile
from collections.abc import Callable
from typing import Any, ClassVar

import numpy as np
from pydantic import BaseModel

from adclient.builtin_learners import BatchPPOOptions
from adworker.batched import BatchedEnv
from adworker.checkpoints import MAX_CHECKPOINT_BYTES, CheckpointError
from adworker.learners import Learner, learner_device, release_batch
from adworker.npy_archives import ArchiveError, check_npz
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
    no_check,
)
from adworker.tasks.base import RobotEnv

log = logging.getLogger("adworker")

ALGORITHM = "ppo-batch"
FORMAT = 1
CHECK_EVERY = 64
"""Env steps (all worlds together) between calls of a job's ``check``."""
LOG_2PI = math.log(2.0 * math.pi)


class Networks:
    """The actor (mean of a Gaussian, its log standard deviation a parameter) and the
    critic, torch modules for the update and NumPy copies for the rollout."""

    def __init__(
        self, observations: int, actions: int, arch: list[int], log_std: float, seed: int
    ) -> None:
        import torch
        from torch import nn

        torch.manual_seed(seed)

        def mlp(out: int, gain: float) -> nn.Sequential:
            layers: list[nn.Module] = []
            width = observations
            for hidden in arch:
                linear = nn.Linear(width, hidden)
                nn.init.orthogonal_(linear.weight, math.sqrt(2.0))
                nn.init.zeros_(linear.bias)
                layers += [linear, nn.Tanh()]
                width = hidden
            head = nn.Linear(width, out)
            nn.init.orthogonal_(head.weight, gain)
            nn.init.zeros_(head.bias)
            return nn.Sequential(*layers, head)

        self.actor = mlp(actions, 0.01)
        self.critic = mlp(1, 1.0)
        self.log_std = nn.Parameter(torch.full((actions,), float(log_std)))
        self.observations, self.actions = observations, actions
        self.parameters: list[Any] = [
            *self.actor.parameters(),
            *self.critic.parameters(),
            self.log_std,
        ]
        self.refresh()

    def refresh(self) -> None:
        """Copy the weights into the NumPy forms the rollout evaluates."""

        def layers(net: Any) -> list[tuple[np.ndarray, np.ndarray]]:
            linears = [m for m in net if hasattr(m, "weight")]
            return [
                (m.weight.detach().cpu().numpy().T.copy(), m.bias.detach().cpu().numpy().copy())
                for m in linears
            ]

        self._actor = layers(self.actor)
        self._critic = layers(self.critic)
        self.std = np.exp(self.log_std.detach().cpu().numpy()).astype(np.float32)

    @staticmethod
    def _forward(layers: list[tuple[np.ndarray, np.ndarray]], x: np.ndarray) -> np.ndarray:
        for weight, bias in layers[:-1]:
            x = np.tanh(x @ weight + bias)
        weight, bias = layers[-1]
        return x @ weight + bias

    def mean(self, observations: np.ndarray) -> np.ndarray:
        return self._forward(self._actor, observations)

    def value(self, observations: np.ndarray) -> np.ndarray:
        return self._forward(self._critic, observations)[..., 0]

    def state(self) -> dict[str, np.ndarray]:
        named = {f"actor.{k}": v for k, v in self.actor.state_dict().items()}
        named |= {f"critic.{k}": v for k, v in self.critic.state_dict().items()}
        named["log_std"] = self.log_std.detach()
        return {k: v.detach().cpu().numpy() for k, v in named.items()}

    def load(self, arrays: dict[str, np.ndarray]) -> None:
        import torch

        for prefix, net in (("actor.", self.actor), ("critic.", self.critic)):
            own = net.state_dict()
            given = {k[len(prefix) :]: v for k, v in arrays.items() if k.startswith(prefix)}
            _fits(own, given, prefix)
            net.load_state_dict({k: torch.as_tensor(v) for k, v in given.items()})
        _fits({"log_std": self.log_std}, {"log_std": arrays.get("log_std")}, "")
        with torch.no_grad():
            self.log_std.copy_(torch.as_tensor(arrays["log_std"]))
        self.refresh()

    def to(self, device: str) -> None:
        """Move the networks to the torch device the update runs on (the rollout's
        copies stay NumPy)."""
        self.actor.to(device)
        self.critic.to(device)
        self.log_std.data = self.log_std.data.to(device)  # in place: the same Parameter


def _fits(own: dict[str, Any], given: dict[str, Any], prefix: str) -> None:
    if set(own) != set(given):
        raise CheckpointError(
            f"{prefix or 'the policy'}: arrays {sorted(given)} where this design's networks "
            f"have {sorted(own)} (another net_arch)"
        )
    for name, value in own.items():
        array = given[name]
        if array is None or tuple(array.shape) != tuple(value.shape):
            shape = None if array is None else tuple(array.shape)
            raise CheckpointError(
                f"{prefix}{name} is {shape}, this design's networks {tuple(value.shape)} "
                "(another observation or action space, or net_arch)"
            )


class Rollout:
    """One rollout's samples, arrays allocated once: ``unroll`` x ``n_envs``."""

    def __init__(self, unroll: int, worlds: int, observations: int, actions: int) -> None:
        self.observations = np.zeros((unroll, worlds, observations), dtype=np.float32)
        self.actions = np.zeros((unroll, worlds, actions), dtype=np.float32)
        self.log_probs = np.zeros((unroll, worlds), dtype=np.float32)
        self.values = np.zeros((unroll, worlds), dtype=np.float32)
        self.rewards = np.zeros((unroll, worlds), dtype=np.float32)
        self.dones = np.zeros((unroll, worlds), dtype=np.float32)
        self.advantages = np.zeros((unroll, worlds), dtype=np.float32)

    def gae(self, last_values: np.ndarray, length: int, gamma: float, lam: float) -> np.ndarray:
        """Advantages of the first ``length`` steps (all worlds at once); returns them,
        the value targets being ``advantages + values``."""
        running = np.zeros_like(last_values)
        next_values = last_values
        for t in range(length - 1, -1, -1):
            alive = 1.0 - self.dones[t]
            delta = self.rewards[t] + gamma * next_values * alive - self.values[t]
            running = delta + gamma * lam * alive * running
            self.advantages[t] = running
            next_values = self.values[t]
        return self.advantages[:length]


class BatchPPOLearner(Learner):
    """See the module docstring."""

    name: ClassVar[str] = ALGORITHM
    default_steps: ClassVar[int] = BatchPPOOptions.default_steps

    def __init__(self, options: BaseModel | None = None) -> None:
        super().__init__(options)
        chosen = options if options is not None else BatchPPOOptions()
        if not isinstance(chosen, BatchPPOOptions):
            raise TypeError(f"{self.name} takes BatchPPOOptions, not {chosen!r}")
        self.settings = chosen

    # ------------------------------------------------------------------ building

    def networks(self, env: Any, seed: int) -> Networks:
        observations = int(env.observation_space.shape[0])
        actions = int(env.action_space.shape[0])
        return Networks(
            observations, actions, list(self.settings.net_arch), self.settings.log_std_init, seed
        )

    def optimiser(self, networks: Networks) -> Any:
        import torch

        return torch.optim.Adam(
            networks.parameters, lr=self.settings.learning_rate, eps=1e-5, foreach=True
        )

    # ------------------------------------------------------------------ training

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
        import torch

        torch.set_num_threads(1)
        self.warm_problem = None
        networks = self.networks(env, seed)
        networks.to(learner_device())
        optimiser = self.optimiser(networks)
        done_steps = 0
        warm = False
        if isinstance(start, Resume):
            done_steps = load(networks, optimiser, start.checkpoint)
            if reporting is not None:
                reporting.resume_at(done_steps)
            seed += done_steps  # not the exploration it started with
        elif isinstance(start, Warm):
            try:
                load(networks, optimiser, start.checkpoint)
            except CheckpointError as error:
                self.warm_problem = f"{type(error).__name__}: {error}"
                log.warning("warm start refused (%s): training from scratch", self.warm_problem)
            else:
                warm, steps = True, start.steps
        elif isinstance(start, Shared):
            self.warm_problem = f"the {self.name} learner has no shared controller (ppo has)"
            log.warning("shared start refused (%s): training from scratch", self.warm_problem)
        batch = BatchedEnv.of(env, self.settings.n_envs)
        curve: list[dict[str, float]] = []
        try:
            done_steps = self._learn(
                batch, networks, optimiser, steps, done_steps, seed, check, reporting, curve
            )
        except Pruned as stopped:
            if stopped.pause:
                stopped.checkpoint = save(networks, optimiser, stopped.step)
            raise
        finally:
            release_batch(batch, env)
        return TrainResult(
            policy=deterministic(networks),
            train_steps=done_steps,
            curve=curve,
            info={"algorithm": ALGORITHM, "n_envs": self.settings.n_envs},
            checkpoint=save(networks, optimiser, done_steps) if keep_checkpoint else None,
            warm_started=warm,
        )

    def _learn(
        self,
        batch: BatchedEnv,
        networks: Networks,
        optimiser: Any,
        steps: int,
        done: int,
        seed: int,
        check: Callable[[], None],
        reporting: Reporting | None,
        curve: list[dict[str, float]],
    ) -> int:
        settings = self.settings
        worlds = batch.num_envs
        unroll = settings.unroll
        rollout = Rollout(unroll, worlds, networks.observations, networks.actions)
        rng = np.random.default_rng(seed)
        generator = _torch_generator(seed)
        batch.seed(seed)
        observations: Any = batch.reset()
        gamma = settings.gamma
        while done < steps:
            length = min(unroll, math.ceil((steps - done) / worlds))
            for t in range(length):
                mean = networks.mean(observations)
                noise = rng.standard_normal(mean.shape).astype(np.float32)
                actions = mean + networks.std * noise
                rollout.observations[t] = observations
                rollout.actions[t] = actions
                rollout.log_probs[t] = _log_prob_of_noise(noise, networks.std)
                rollout.values[t] = networks.value(observations)
                observations, rewards, dones, infos = batch.step(np.clip(actions, -1.0, 1.0))
                before = done
                done += worlds
                for i in np.flatnonzero(dones):
                    info = infos[i]
                    if "score" in info:
                        curve.append({"steps": float(done), "score": float(info["score"])})
                    if info.get("TimeLimit.truncated"):
                        terminal = np.asarray(info["terminal_observation"], dtype=np.float32)
                        rewards[i] += gamma * float(networks.value(terminal[None])[0])
                rollout.rewards[t] = rewards
                rollout.dones[t] = dones
                if done // CHECK_EVERY > before // CHECK_EVERY:
                    check()
            advantages = rollout.gae(
                networks.value(observations), length, gamma, settings.gae_lambda
            )
            self._update(networks, optimiser, rollout, advantages, length, generator)
            networks.refresh()
            if reporting is not None and reporting.due <= done < steps:
                reporting.send(done, reporting.evaluate(deterministic(networks)))
        return done

    def _update(
        self,
        networks: Networks,
        optimiser: Any,
        rollout: Rollout,
        advantages: np.ndarray,
        length: int,
        generator: Any,
    ) -> None:
        import torch

        settings = self.settings
        device = learner_device()

        def flat(array: np.ndarray) -> Any:
            return torch.as_tensor(array[:length].reshape(length * array.shape[1], -1)).to(device)

        observations = flat(rollout.observations)
        actions = flat(rollout.actions)
        old_log_probs = flat(rollout.log_probs)[:, 0]
        values = flat(rollout.values)[:, 0]
        gains = torch.as_tensor(advantages.reshape(-1)).to(device)
        returns = gains + values
        count = observations.shape[0]
        minibatches = min(settings.n_minibatches, count)
        size = math.ceil(count / minibatches)
        clip = settings.clip_range
        for _ in range(settings.n_epochs):
            order = torch.randperm(count, generator=generator).to(device)
            for first in range(0, count, size):
                chosen = order[first : first + size]
                gain = gains[chosen]
                if gain.numel() > 1:
                    gain = (gain - gain.mean()) / (gain.std() + 1e-8)
                mean = networks.actor(observations[chosen])
                log_std = networks.log_std
                z = (actions[chosen] - mean) / log_std.exp()
                log_prob = (-0.5 * z.pow(2) - log_std - 0.5 * LOG_2PI).sum(-1)
                ratio = (log_prob - old_log_probs[chosen]).exp()
                surrogate = torch.min(gain * ratio, gain * ratio.clamp(1.0 - clip, 1.0 + clip))
                value = networks.critic(observations[chosen])[:, 0]
                value_loss = (returns[chosen] - value).pow(2).mean()
                entropy = (log_std + 0.5 * (1.0 + LOG_2PI)).sum()
                loss = (
                    -surrogate.mean() + settings.vf_coef * value_loss - settings.ent_coef * entropy
                )
                optimiser.zero_grad(set_to_none=True)
                loss.backward()
                torch.nn.utils.clip_grad_norm_(
                    networks.parameters, settings.max_grad_norm, foreach=True
                )
                optimiser.step()


def _log_prob_of_noise(noise: np.ndarray, std: np.ndarray) -> np.ndarray:
    """The Gaussian log-probability of ``mean + std * noise`` under the policy."""
    return (-0.5 * noise * noise - np.log(std) - 0.5 * LOG_2PI).sum(-1)


def _torch_generator(seed: int) -> Any:
    import torch

    generator = torch.Generator()
    generator.manual_seed(seed)
    return generator


def deterministic(networks: Networks) -> Policy:
    """The policy's mean action, clipped to the action space (a copy of the weights: a
    later update does not change it)."""
    actor = [(w.copy(), b.copy()) for w, b in networks._actor]

    def policy(observation: np.ndarray) -> np.ndarray:
        x = np.asarray(observation, dtype=np.float32)
        mean = Networks._forward(actor, x[None] if x.ndim == 1 else x)
        action = np.clip(mean, -1.0, 1.0).astype(np.float32)
        return action[0] if x.ndim == 1 else action

    return policy


# ---------------------------------------------------------------------- checkpoints

META = ("format", "num_timesteps", "adam_step")
"""The scalars a checkpoint holds beside the arrays: its format, the steps trained and
Adam's step count."""


def save(networks: Networks, optimiser: Any, num_timesteps: int) -> bytes:
    """The networks, Adam's moments and the steps trained, as one ``.npz`` of numbers."""
    arrays = networks.state()
    for index, parameter in enumerate(networks.parameters):
        moments = optimiser.state.get(parameter, {})
        for moment in ("exp_avg", "exp_avg_sq"):
            if moment in moments:
                arrays[f"adam.{index}.{moment}"] = moments[moment].detach().cpu().numpy()
    steps = [int(s.get("step", 0)) for s in optimiser.state.values()] or [0]
    arrays["format"] = np.array(FORMAT, dtype=np.int64)
    arrays["num_timesteps"] = np.array(num_timesteps, dtype=np.int64)
    arrays["adam_step"] = np.array(max(steps), dtype=np.int64)
    with io.BytesIO() as out:
        np.savez_compressed(out, allow_pickle=False, **arrays)
        return out.getvalue()


def load(networks: Networks, optimiser: Any, checkpoint: bytes) -> int:
    """Fill ``networks`` and ``optimiser`` (built for this design from the job's own
    settings) from a :func:`save`d checkpoint: the steps it had trained.
    CheckpointError when it is not one or does not fit; nothing in it is unpickled."""
    import torch

    try:
        with zipfile.ZipFile(io.BytesIO(checkpoint)) as archive:
            check_npz(archive, MAX_CHECKPOINT_BYTES, "the checkpoint")
        with np.load(io.BytesIO(checkpoint), allow_pickle=False) as read:
            arrays = {name: read[name] for name in read.files}
    except (zipfile.BadZipFile, ArchiveError, ValueError, OSError) as error:
        raise CheckpointError(f"not a {ALGORITHM} checkpoint ({error})") from None
    if any(name not in arrays or arrays[name].shape != () for name in META):
        raise CheckpointError(f"not a {ALGORITHM} checkpoint (it has no {', '.join(META)})")
    if int(arrays["format"]) != FORMAT:
        raise CheckpointError(f"a {ALGORITHM} checkpoint of format {int(arrays['format'])}")
    networks.load({k: v for k, v in arrays.items() if not k.startswith("adam.")})
    adam_step = int(arrays["adam_step"])
    for index, parameter in enumerate(networks.parameters):
        names = [f"adam.{index}.exp_avg", f"adam.{index}.exp_avg_sq"]
        if not all(name in arrays for name in names):
            continue
        moments = [torch.as_tensor(arrays[name]).to(parameter.device) for name in names]
        if any(tuple(m.shape) != tuple(parameter.shape) for m in moments):
            raise CheckpointError(f"Adam's moments of parameter {index} do not fit it")
        optimiser.state[parameter] = {
            "step": torch.tensor(float(adam_step)),  # on the CPU, as Adam keeps it
            "exp_avg": moments[0].float(),
            "exp_avg_sq": moments[1].float(),
        }
    return max(int(arrays["num_timesteps"]), 0)
