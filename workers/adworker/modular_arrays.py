"""The modular policy's acting in NumPy (:mod:`adworker.modular`): a rollout's step and an
evaluation's action, one observation at a time without gradients, where torch's cost per
operation (some 60 of them a step) outweighs the arithmetic. Only for a policy on the
CPU; the policy falls back to torch's modules otherwise."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch


class ArrayForward:
    """The extractor's, value's and action mean's forward pass in NumPy, float32, for a
    policy on the CPU: the same arithmetic as the torch modules (tested equal within
    rounding). It reads each parameter's current values at every call (views of
    torch's storage), so an optimiser step or a loaded version is never stale."""

    def __init__(self, policy: Any) -> None:
        self.policy = policy
        extractor = policy.mlp_extractor
        layout = extractor.blocks.layout
        self.layout = layout
        links = len(layout.owner)
        owns = np.zeros((layout.joint_count + 1, links), dtype=bool)
        owns[list(layout.owner), list(range(links))] = True
        self.owns = owns
        self.joint_static = np.asarray(layout.joint_static, dtype=np.float32)
        self.global_static = np.asarray(layout.global_static, dtype=np.float32)
        self.parent = extractor.parent.cpu().numpy()

    def __call__(self, observation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Observations ``[batch, size]`` -> (action means ``[batch, joints]``, values
        ``[batch, 1]``)."""
        layout, policy = self.layout, self.policy
        extractor = policy.mlp_extractor
        tree = extractor.tree
        batch, count = observation.shape[0], layout.joint_count
        links = len(layout.owner)

        def part(start: int | None, size: int) -> np.ndarray:
            if start is None:
                return np.zeros((batch, size), dtype=np.float32)
            return observation[:, start : start + size]

        def per_node(values: np.ndarray) -> np.ndarray:
            return np.where(self.owns, values[:, None, :], -np.inf).max(axis=-1)

        height = per_node(part(layout.heights, links)).astype(np.float32)
        contact = per_node(part(layout.contacts, links)).astype(np.float32)
        dynamic = np.stack(
            (
                observation[:, :count],
                observation[:, count : 2 * count],
                height[:, 1:],
                contact[:, 1:],
            ),
            axis=-1,
        )
        static = np.broadcast_to(self.joint_static, (batch, *self.joint_static.shape))
        overall = np.concatenate(
            (
                part(layout.base, 4),
                height[:, :1],
                contact[:, :1],
                part(layout.clock, 2),
                np.broadcast_to(self.global_static, (batch, len(self.global_static))),
                part(layout.extras, layout.extras_size),
            ),
            axis=-1,
        )
        everywhere = np.broadcast_to(overall[:, None, :], (batch, count, overall.shape[-1]))
        inputs = np.concatenate((dynamic, static, everywhere), axis=-1).reshape(batch * count, -1)
        heads, hidden, nodes = tree.heads, tree.hidden, count + 1
        state = np.concatenate(
            (
                np.tanh(_stacked(tree.root_in, overall)).reshape(heads, batch, 1, hidden),
                np.tanh(_stacked(tree.joint_in, inputs)).reshape(heads, batch, count, hidden),
            ),
            axis=2,
        )
        for message, update in zip(tree.message, tree.update, strict=True):
            sent = _stacked(message, state.reshape(heads, batch * nodes, hidden))
            sent = sent.reshape(heads, batch, nodes, 2 * hidden)
            up, down = sent[..., :hidden], sent[..., hidden:]
            gathered = np.concatenate((state, self.parent.T @ up, self.parent @ down), axis=-1)
            change = _stacked(update, gathered.reshape(heads, batch * nodes, 3 * hidden))
            state = state + np.tanh(change.reshape(heads, batch, nodes, hidden))
        critic = state[1]
        pooled = np.concatenate((critic[:, 1:].mean(axis=1), critic[:, 0]), axis=-1)
        latent_vf = np.tanh(_linear(extractor.pool, pooled))
        values = _linear(policy.value_net, latent_vf)
        means = _linear(policy.action_net.linear, state[0, :, 1:])[..., 0]
        return means, values


def _values(parameter: torch.Tensor) -> np.ndarray:
    return parameter.detach().numpy()


def _stacked(layer: Any, values: np.ndarray) -> np.ndarray:
    """A :class:`StackedLinear`'s product."""
    return np.matmul(values, _values(layer.weight)) + _values(layer.bias)


def _linear(layer: Any, values: np.ndarray) -> np.ndarray:
    """An ``nn.Linear``'s product."""
    return values @ _values(layer.weight).T + _values(layer.bias)
