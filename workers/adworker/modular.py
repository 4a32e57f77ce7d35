"""One controller for every design of a study (``task.transfer: shared``): a modular
PPO policy whose weights fit any tree of a design space, any joint count.

The modular observation (:class:`ModularLayout`) regroups a task env's flat
observation (``RobotEnv._observe``) into one block per driven joint and one global
block, each of a size that depends on the task alone:

- a joint's block: its position and velocity (normalised as the env gives them), the
  height of the highest link it carries and whether any of them touches the ground
  (a joint carries its child link and the links fixed to it), then static features
  of its design: its axis (unit), kind (prismatic or not), range, effort and speed,
  its child link's length, radius and carried mass, its depth in the tree and its
  number of driven children;
- the global block: the free base's tilt and height, the root's highest link and
  contact, the gait clock (zeros for a fixed base or a task without one), the root
  link's length, radius and mass, the whole robot's mass and joint count, then the
  task's extras (``Task.observation``).

A value the task does not observe (a fixed base's pose, contacts a task does not
read) is 0. The tree's topology (each joint's parent joint, or the root) is the
layout's, read from the env when the model is built. A task whose extras' size
depends on the design does not fit across designs: its weights are refused by
:func:`load_shared` with the array that does not fit.

The policy (:class:`ModularPolicy`, after Huang, Mordatch and Pathak, "One Policy to
Control Them All", ICML 2020): one encoder shared by all joints (its block plus the
global block) and one for the root (the global block), then a few rounds of messages
along the tree (each node adds what its children and its parent send), a per-joint
action head (one action per joint), a critic pooled over the joints plus the root, and
one log-std shared by all joints. Actor and critic have networks of their own, computed
together as two heads of stacked weights (:class:`StackedLinear`). Every
parameter's shape is independent of the joint count, so the same weights
(:func:`shared_weights_of`, in :mod:`adworker.shared_weights`' format) load into the
model of any design of the study; the model takes the env's raw observation, so its
policy is evaluated on the plain env like any other.

The study's initial weights (:func:`initial_weights`) depend on its task and seed
only: the same on every worker and process, whichever design asks.

Acting (a rollout's step, an evaluation's action) runs on one observation at a time
without gradients, where torch's cost per operation (some 60 of them a step) outweighs
the arithmetic: on the CPU the policy then computes the same numbers in NumPy from its
parameters' current values (:class:`adworker.modular_arrays.ArrayForward`), and only the
action's draw stays torch's (its random stream is the one a seed fixes). Training's
batches keep torch's autograd.
"""

from __future__ import annotations

import functools
import logging
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from stable_baselines3.common.distributions import DiagGaussianDistribution
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.torch_layers import FlattenExtractor
from torch import nn

from adworker.modular_arrays import ArrayForward
from adworker.shared_weights import SharedWeightsError, Weights, actor_part
from adworker.tasks.base import RobotEnv

log = logging.getLogger("adworker")

JOINT_DYNAMIC = ("position", "velocity", "height", "contact")
JOINT_STATIC = (
    "axis_x",
    "axis_y",
    "axis_z",
    "prismatic",
    "range",
    "effort",
    "speed",
    "length",
    "radius",
    "mass",
    "depth",
    "children",
)
GLOBAL_FIXED = (
    "tilt_x",
    "tilt_y",
    "tilt_z",
    "base_height",
    "root_height",
    "root_contact",
    "clock_sin",
    "clock_cos",
    "root_length",
    "root_radius",
    "root_mass",
    "total_mass",
    "joints",
)
"""The global block's named values; the task's extras follow them."""
HIDDEN = 64
ROUNDS = 2


@dataclass(frozen=True)
class ModularLayout:
    """Where each block's values sit in one design's flat observation, its static
    features and its tree. Nodes: 0 the root, ``j + 1`` driven joint ``j`` (the env's
    action order)."""

    observation_size: int
    joint_count: int
    parents: tuple[int, ...]
    """Per joint, the node of its parent: 0 the root, ``k + 1`` joint ``k``."""
    base: int | None
    """Offset of the free base's tilt (3) and height; None: a fixed base."""
    heights: int | None
    """Offset of the links' heights (one per link, the env's link order)."""
    contacts: int | None
    extras: int
    extras_size: int
    clock: int | None
    owner: tuple[int, ...]
    """Per link, the node that carries it."""
    joint_static: tuple[tuple[float, ...], ...]
    global_static: tuple[float, ...]

    @property
    def joint_size(self) -> int:
        return len(JOINT_DYNAMIC) + len(JOINT_STATIC)

    @property
    def global_size(self) -> int:
        return len(GLOBAL_FIXED) + self.extras_size

    def blocks(self, observation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """One flat observation as (joint blocks ``[joints, joint_size]``, global block)."""
        split = Blocks(self)
        with torch.no_grad():
            joints, overall = split(torch.as_tensor(observation, dtype=torch.float32)[None])
        return joints[0].numpy(), overall[0].numpy()


def layout_of(env: Any) -> ModularLayout:
    """The modular layout of a task env (a ``RobotEnv``, or a wrapper of one)."""
    env = env.unwrapped
    if not isinstance(env, RobotEnv):
        raise TypeError(f"the modular policy needs a RobotEnv, not {type(env).__name__}")
    robot = env.robot
    model = robot.model
    joints = robot.joints
    count = len(joints)
    node_of_link = {joint.child: j + 1 for j, joint in enumerate(joints)}
    joint_to = {joint.child: joint for joint in model.joints}
    model_joint = {joint.name: joint for joint in model.joints}

    def node(link: str) -> int:
        while link not in node_of_link and link in joint_to:
            link = joint_to[link].parent
        return node_of_link.get(link, 0)

    parents = tuple(node(model_joint[joint.name].parent) for joint in joints)
    owner = tuple(node(g.name) for g in robot.geometry)
    depth = [0] * (count + 1)
    for j, parent in enumerate(parents):  # the engine's order is depth first
        depth[j + 1] = depth[parent] + 1
    mass = [0.0] * (count + 1)
    for g, k in zip(robot.geometry, owner, strict=True):
        mass[k] += g.mass
    geometry = {g.name: g for g in robot.geometry}
    static = []
    for j, joint in enumerate(joints):
        axis = np.asarray(model_joint[joint.name].axis, dtype=float)
        axis = axis / max(float(np.linalg.norm(axis)), 1e-9)
        child = geometry[joint.child]
        static.append(
            (
                *(float(v) for v in axis),
                float(model_joint[joint.name].kind == "prismatic"),
                (joint.upper - joint.lower) / math.pi,
                math.log1p(joint.effort) / 3.0,
                math.log1p(joint.velocity) / 3.0,
                child.length,
                10.0 * max(child.radius, child.ball),
                mass[j + 1],
                depth[j + 1] / 4.0,
                sum(parent == j + 1 for parent in parents) / 4.0,
            )
        )
    root = robot.geometry[0]
    global_static = (
        root.length,
        10.0 * max(root.radius, root.ball),
        mass[0],
        sum(mass),
        count / 8.0,
    )
    links = len(robot.geometry)
    offset = 2 * count
    base = heights = contacts = None
    if not robot.fixed_base:
        base, heights = offset, offset + 4
        offset += 4 + links
    if robot.reads_contacts:
        contacts = offset
        offset += links
    extras_size = env.task.observation_size()
    clock = None if env.gait_period is None else offset + extras_size
    size = int(np.prod(env.observation_space.shape or (0,)))
    if size != offset + extras_size + (0 if clock is None else 2):
        raise ValueError(f"an observation of {size} values is not the layout's")
    return ModularLayout(
        observation_size=size,
        joint_count=count,
        parents=parents,
        base=base,
        heights=heights,
        contacts=contacts,
        extras=offset,
        extras_size=extras_size,
        clock=clock,
        owner=owner,
        joint_static=tuple(static),
        global_static=global_static,
    )


class Blocks(nn.Module):
    """Flat observations ``[batch, size]`` -> (joint blocks ``[batch, joints,
    joint_size]``, global blocks ``[batch, global_size]``); no parameters."""

    carries: torch.Tensor
    joint_static: torch.Tensor
    global_static: torch.Tensor

    def __init__(self, layout: ModularLayout) -> None:
        super().__init__()
        self.layout = layout
        nodes = layout.joint_count + 1
        owns = torch.zeros(nodes, len(layout.owner), dtype=torch.bool)
        owns[list(layout.owner), list(range(len(layout.owner)))] = True
        self.register_buffer("carries", ~owns, persistent=False)
        self.register_buffer(
            "joint_static", torch.tensor(layout.joint_static, dtype=torch.float32), persistent=False
        )
        self.register_buffer(
            "global_static",
            torch.tensor(layout.global_static, dtype=torch.float32),
            persistent=False,
        )

    def _per_node(self, values: torch.Tensor) -> torch.Tensor:
        """Per link ``[batch, links]`` -> the largest of each node's links."""
        carried = values[:, None, :].masked_fill(self.carries, -math.inf)
        return carried.amax(dim=-1)

    def forward(self, observation: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        layout = self.layout
        batch, count = observation.shape[0], layout.joint_count
        links = len(layout.owner)

        def part(start: int | None, size: int) -> torch.Tensor:
            if start is None:
                return observation.new_zeros(batch, size)
            return observation[:, start : start + size]

        heights = part(layout.heights, links)
        contacts = part(layout.contacts, links)
        height, contact = self._per_node(heights), self._per_node(contacts)
        dynamic = torch.stack(
            (
                observation[:, :count],
                observation[:, count : 2 * count],
                height[:, 1:],
                contact[:, 1:],
            ),
            dim=-1,
        )
        static = self.joint_static.expand(batch, -1, -1)
        joints = torch.cat((dynamic, static), dim=-1)
        overall = torch.cat(
            (
                part(layout.base, 4),
                height[:, :1],
                contact[:, :1],
                part(layout.clock, 2),
                self.global_static.expand(batch, -1),
                part(layout.extras, layout.extras_size),
            ),
            dim=-1,
        )
        return joints, overall


class StackedLinear(nn.Module):
    """``heads`` linear layers of one size, applied in one batched product: ``[heads or
    1, rows, size_in]`` -> ``[heads, rows, size_out]``. The actor's and the critic's
    networks are such heads: separate weights, half the operations per step (a policy
    acting on one observation at a time pays per operation, not per number)."""

    def __init__(self, heads: int, size_in: int, size_out: int) -> None:
        super().__init__()
        self.weight = nn.Parameter(torch.empty(heads, size_in, size_out))
        self.bias = nn.Parameter(torch.zeros(heads, 1, size_out))
        bound = 1.0 / math.sqrt(size_in)  # nn.Linear's default
        nn.init.uniform_(self.weight, -bound, bound)
        nn.init.uniform_(self.bias, -bound, bound)

    def orthogonal(self, gain: float) -> None:
        """Each head's weights orthogonal, its bias zero (SB3's ``ortho_init``)."""
        with torch.no_grad():
            for head in self.weight:
                nn.init.orthogonal_(head, gain=gain)
            self.bias.zero_()

    def forward(self, values: torch.Tensor) -> torch.Tensor:
        heads = self.weight.shape[0]
        return torch.baddbmm(self.bias, values.expand(heads, -1, -1), self.weight)


class TreeNet(nn.Module):
    """Encoders, then ``rounds`` of messages along the tree, for ``heads`` networks at
    once (the actor's and the critic's); ``[heads, batch, nodes, hidden]`` out (node 0
    the root)."""

    def __init__(
        self, joint_size: int, global_size: int, hidden: int, rounds: int, heads: int = 2
    ) -> None:
        super().__init__()
        self.joint_in = StackedLinear(heads, joint_size + global_size, hidden)
        self.root_in = StackedLinear(heads, global_size, hidden)
        self.hidden, self.heads = hidden, heads
        self.message = nn.ModuleList(
            StackedLinear(heads, hidden, 2 * hidden) for _ in range(rounds)
        )
        """Per round, what a node sends up to its parent and down to its children."""
        self.update = nn.ModuleList(StackedLinear(heads, 3 * hidden, hidden) for _ in range(rounds))

    def forward(
        self, joints: torch.Tensor, overall: torch.Tensor, parent: torch.Tensor
    ) -> torch.Tensor:
        batch, count = joints.shape[:2]
        heads, hidden, nodes = self.heads, self.hidden, count + 1
        everywhere = overall[:, None, :].expand(-1, count, -1)
        inputs = torch.cat((joints, everywhere), dim=-1).reshape(1, batch * count, -1)
        state = torch.cat(
            (
                torch.tanh(self.root_in(overall[None])).reshape(heads, batch, 1, hidden),
                torch.tanh(self.joint_in(inputs)).reshape(heads, batch, count, hidden),
            ),
            dim=2,
        )
        for message, update in zip(self.message, self.update, strict=True):
            sent = message(state.reshape(heads, batch * nodes, hidden))
            up, down = sent.reshape(heads, batch, nodes, 2 * hidden).split(hidden, dim=-1)
            gathered = torch.cat((state, parent.T @ up, parent @ down), dim=-1)
            change = update(gathered.reshape(heads, batch * nodes, 3 * hidden))
            state = state + torch.tanh(change.reshape(heads, batch, nodes, hidden))
        return state


class ModularExtractor(nn.Module):
    """The policy's ``mlp_extractor``: per-joint latents for the actor, a pooled one
    for the critic, from one :class:`TreeNet` of two heads (actor 0, critic 1)."""

    parent: torch.Tensor

    def __init__(self, layout: ModularLayout, hidden: int, rounds: int) -> None:
        super().__init__()
        self.blocks = Blocks(layout)
        nodes = layout.joint_count + 1
        parent = torch.zeros(nodes, nodes)
        for j, p in enumerate(layout.parents):
            parent[j + 1, p] = 1.0
        self.register_buffer("parent", parent, persistent=False)
        self.tree = TreeNet(layout.joint_size, layout.global_size, hidden, rounds)
        self.pool = nn.Linear(2 * hidden, hidden)
        self.latent_dim_pi = hidden
        self.latent_dim_vf = hidden

    def forward(self, features: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        state = self.tree(*self.blocks(features), self.parent)
        return state[0, :, 1:], self._pooled(state[1])

    def forward_actor(self, features: torch.Tensor) -> torch.Tensor:
        return self.forward(features)[0]

    def forward_critic(self, features: torch.Tensor) -> torch.Tensor:
        return self.forward(features)[1]

    def _pooled(self, state: torch.Tensor) -> torch.Tensor:
        pooled = torch.cat((state[:, 1:].mean(dim=1), state[:, 0]), dim=-1)
        return torch.tanh(self.pool(pooled))


class JointHead(nn.Module):
    """One action per joint from its latent: ``[batch, joints, hidden]`` -> ``[batch,
    joints]``."""

    def __init__(self, hidden: int) -> None:
        super().__init__()
        self.linear = nn.Linear(hidden, 1)

    def forward(self, latent: torch.Tensor) -> torch.Tensor:
        return self.linear(latent).squeeze(-1)


class ModularPolicy(ActorCriticPolicy):
    """SB3's actor-critic over a :class:`ModularLayout` (``policy_kwargs``: ``layout``,
    ``hidden``, ``rounds``); see the module docstring."""

    def __init__(
        self,
        *args: Any,
        layout: ModularLayout,
        hidden: int = HIDDEN,
        rounds: int = ROUNDS,
        **kwargs: Any,
    ) -> None:
        self.layout, self.hidden, self.rounds = layout, hidden, rounds
        super().__init__(*args, **kwargs)

    def _build_mlp_extractor(self) -> None:
        self.mlp_extractor = ModularExtractor(  # type: ignore[assignment]
            self.layout, self.hidden, self.rounds
        )

    def _build(self, lr_schedule: Any) -> None:
        if not isinstance(self.action_dist, DiagGaussianDistribution):
            raise ValueError("the modular policy acts with a diagonal Gaussian (no gSDE)")
        self._build_mlp_extractor()
        self.action_net = JointHead(self.hidden)
        self.log_std = nn.Parameter(torch.full((1,), float(self.log_std_init)))
        self.value_net = nn.Linear(self.hidden, 1)
        if self.ortho_init:
            gains = {self.mlp_extractor: math.sqrt(2), self.action_net: 0.01, self.value_net: 1.0}
            for module, gain in gains.items():
                module.apply(functools.partial(self.init_weights, gain=gain))
            for part in self.mlp_extractor.modules():
                if isinstance(part, StackedLinear):
                    part.orthogonal(math.sqrt(2))
        self.optimizer = self.optimizer_class(  # type: ignore[call-arg]
            self.parameters(), lr=lr_schedule(1), **self.optimizer_kwargs
        )

    def _arrays(self, observation: torch.Tensor) -> tuple[np.ndarray, np.ndarray] | None:
        """The action means and values in NumPy (:class:`ArrayForward`), or None where
        torch must compute them: a gradient is wanted, or the policy is not on the CPU."""
        if torch.is_grad_enabled() or self.device.type != "cpu":
            return None
        arrays = self.__dict__.get("_array_forward")
        if arrays is None:
            arrays = self.__dict__["_array_forward"] = ArrayForward(self)
        if not isinstance(self.features_extractor, FlattenExtractor):
            return None  # another extractor (or one per network): torch's path
        # preprocess_obs of a Box and a flatten: the values as float32 rows
        return arrays(observation.numpy().reshape(len(observation), -1).astype(np.float32))

    def forward(
        self, obs: torch.Tensor, deterministic: bool = False
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """SB3's forward (action, value, log-probability); a rollout's step, which runs
        without gradients, through :class:`ArrayForward`: Normal(means, std)'s
        ``rsample``, its noise drawn from torch's seeded stream, and its log-probability
        summed over the joints, in NumPy."""
        found = self._arrays(obs)
        if found is None:
            return super().forward(obs, deterministic)
        means, values = found
        log_std = self.log_std.detach().numpy()
        if deterministic:
            noise = np.zeros_like(means)
        else:
            noise = torch.empty(means.shape, dtype=torch.float32).normal_().numpy()
        actions = means + noise * np.exp(log_std)
        log_prob = (-0.5 * noise**2 - log_std - 0.5 * math.log(2 * math.pi)).sum(axis=1)
        return (
            torch.from_numpy(actions.reshape((-1, *self.action_space.shape))),  # type: ignore[misc]
            torch.from_numpy(values),
            torch.from_numpy(log_prob.astype(np.float32)),
        )

    def _predict(self, observation: Any, deterministic: bool = False) -> torch.Tensor:
        """An evaluation's action; deterministic on the CPU through :class:`ArrayForward`."""
        found = self._arrays(observation) if deterministic else None
        if found is None:
            return super()._predict(observation, deterministic)
        return torch.from_numpy(found[0])

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update(layout=self.layout, hidden=self.hidden, rounds=self.rounds)
        return data


def policy_kwargs(env: Any) -> dict[str, Any]:
    """The ``policy_kwargs`` of a modular model of ``env``'s design."""
    return {"layout": layout_of(env)}


def shared_weights_of(model: Any) -> Weights:
    """A modular model's weights (its policy's whole state), named as the format
    requires; the same names and shapes for every design of the study."""
    return _weights(model.policy)


def load_shared(model: Any, weights: Weights) -> None:
    """Load shared weights into a modular model of any design of the study;
    :class:`SharedWeightsError` naming what does not fit (nothing is loaded then)."""
    policy = model.policy
    expected = policy.state_dict()
    missing = sorted(set(expected) - set(weights))
    extra = sorted(set(weights) - set(expected))
    if missing:
        raise SharedWeightsError(f"the weights have no array {missing[0]!r} (of {len(missing)})")
    if extra:
        raise SharedWeightsError(f"this policy has no array {extra[0]!r} (of {len(extra)})")
    for name, value in expected.items():
        if tuple(weights[name].shape) != tuple(value.shape):
            raise SharedWeightsError(
                f"array {name!r} is {tuple(weights[name].shape)}, this design's policy "
                f"takes {tuple(value.shape)} (another task, or another policy size)"
            )
    state = {
        name: torch.as_tensor(np.asarray(weights[name], dtype=np.float32)).to(value.device)
        for name, value in expected.items()
    }
    policy.load_state_dict(state)


def initial_weights(model: Any, seed: int) -> Weights:
    """The study's initial weights for ``seed``: a fresh policy of the model's task
    and sizes built from a torch generator seeded with ``seed`` on one thread (the
    model's design does not change them: no parameter depends on it), on the CPU."""
    policy = model.policy
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # orthogonal initialisation's QR may round by thread count
    try:
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(seed)
            fresh = type(policy)(**policy._get_constructor_parameters())
    finally:
        torch.set_num_threads(threads)
    return _weights(fresh)


def fresh_actor(model: Any, seed: int) -> None:
    """Put the model's actor (its tree network's actor head, action head and log-std)
    back to the study's initial weights for ``seed``, keeping its critic: a design of a
    shared study that carries the critic alone (``task.shared_carries: critic``)."""
    if not isinstance(model.policy, ModularPolicy):
        log.warning("not the modular policy: its actor is not known, so all of it carries")
        return
    initial = initial_weights(model, seed)
    current = shared_weights_of(model)
    for name, value in current.items():
        actor = actor_part(name, value)
        if actor is not None:
            actor[...] = actor_part(name, initial[name])
    load_shared(model, current)


def _weights(policy: nn.Module) -> Weights:
    return {
        name: value.detach().cpu().numpy().astype(np.float32)
        for name, value in policy.state_dict().items()
    }
