"""Batched worlds (issue 59): N copies of one design doing one task, stepped together,
their observations, rewards and ends read as arrays, as a stable-baselines3 ``VecEnv``
(so SB3's PPO trains on it directly, its policy evaluated once per batch step).

Each world is a :class:`~adworker.tasks.base.RobotEnv` of its own, built over the engine
seam (:mod:`adworker.tasks.engine`), so every task, built-in or a plugin's ``Task``,
runs on the batch unchanged and scores exactly as it does alone:

- MuJoCo: one model compiled per world (the same URDF, so the same model), one
  ``MjData`` each, every world's ``frame_skip`` physics steps one ``mj_step`` call in C;
- PyBullet: one DIRECT client per world. One client holding N bodies would step them in
  one call, but its solver iterates over every body's contacts together and orders
  them by the whole world's pairs: a world's episode would then depend on the others',
  which per-world reproducibility forbids.

Seeds and resets: ``seed(s)`` seeds world i with ``s + i`` at the next ``reset`` (SB3's
convention, what ``DummyVecEnv`` does); a world that ends its episode is reset at once
without a seed, drawing its next start from its own generator, and its last observation
goes in its info as ``terminal_observation``. So world i's episodes depend only on its
seed and the actions it is given: the same as one ``RobotEnv`` seeded ``s + i`` and
stepped with those actions (tests/workers/test_batched.py).

What a batch costs: a world is a whole env (a MuJoCo world about 0.1 MB, a PyBullet
client a few MB); its building, a fraction of a second of CPU, is paid once a job. The
per-world Python of a step (the task's metric and reward, the observation) stays per
world: vectorising it across worlds measured below what it would save (bench/engines.py:
the batch's random-action rate is the single env's), since every world keeps its own
engine data.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from stable_baselines3.common.vec_env import VecEnv
from stable_baselines3.common.vec_env.base_vec_env import VecEnvIndices, VecEnvStepReturn

from adclient.builtin_learners import MAX_BATCH_WORLDS as MAX_WORLDS
from adworker.tasks.base import RobotEnv, Task


def copy_world(env: RobotEnv) -> RobotEnv:
    """Another world of ``env``: the same task, design, URDF, options and engine."""
    task: type[Task[Any]] = type(env.task)
    return RobotEnv(
        task,
        design=env.design,
        urdf_path=env.urdf_path,
        options=env.options,
        simulator=env.simulator,
    )


class BatchedEnv(VecEnv):
    """N worlds of one task env, stepped together; see the module docstring."""

    def __init__(self, worlds: Sequence[RobotEnv]) -> None:
        if not worlds:
            raise ValueError("a batch needs at least one world")
        if len(worlds) > MAX_WORLDS:
            raise ValueError(f"a batch holds at most {MAX_WORLDS} worlds, not {len(worlds)}")
        first = worlds[0]
        self.worlds = list(worlds)
        super().__init__(len(worlds), first.observation_space, first.action_space)
        self._actions: np.ndarray | None = None
        shape = first.observation_space.shape
        assert shape is not None
        self._observations = np.zeros((self.num_envs, *shape), dtype=np.float32)
        self.metadata = first.metadata

    @classmethod
    def of(cls, env: RobotEnv, count: int, *, include: bool = True) -> BatchedEnv:
        """A batch of ``count`` worlds of ``env``'s design; ``include``: ``env`` itself is
        world 0 (its physics steps counted where the job counts them), else all are new.
        Worlds built here are closed by :meth:`close_copies` or :meth:`close`."""
        if not isinstance(env, RobotEnv):
            raise TypeError(
                f"a batch is built of a task env of adworker (RobotEnv), not {type(env).__name__}"
            )
        worlds = [env] if include else []
        try:
            while len(worlds) < count:
                worlds.append(copy_world(env))
        except BaseException:
            for world in worlds[1 if include else 0 :]:
                world.close()
            raise
        batch = cls(worlds)
        batch._owns_first = not include
        return batch

    _owns_first = True
    _copies_closed = False

    @property
    def physics_steps(self) -> int:
        """Physics steps simulated by every world together."""
        return sum(world.sim_steps for world in self.worlds)

    # ------------------------------------------------------------------ VecEnv

    def reset(self) -> np.ndarray:
        for i, world in enumerate(self.worlds):
            options = self._options[i] or None
            observation, self.reset_infos[i] = world.reset(seed=self._seeds[i], options=options)
            self._observations[i] = observation
        self._reset_seeds()
        self._reset_options()
        return self._observations.copy()

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions)

    def step_wait(self) -> VecEnvStepReturn:
        actions = self._actions
        assert actions is not None, "step_async first"
        count = self.num_envs
        rewards = np.zeros(count, dtype=np.float32)
        dones = np.zeros(count, dtype=bool)
        infos: list[dict[str, Any]] = []
        observations = self._observations
        for i, world in enumerate(self.worlds):
            observation, reward, terminated, truncated, info = world.step(actions[i])
            rewards[i] = reward
            info["TimeLimit.truncated"] = truncated and not terminated
            if terminated or truncated:
                dones[i] = True
                info["terminal_observation"] = observation
                observation, self.reset_infos[i] = world.reset()
            observations[i] = observation
            infos.append(info)
        self._actions = None
        return observations.copy(), rewards, dones, infos

    def close_copies(self) -> int:
        """Close the worlds this batch built (not the env it was made of): the physics
        steps they simulated (0 once closed)."""
        if self._copies_closed:
            return 0
        self._copies_closed = True
        copies = self.worlds[0 if self._owns_first else 1 :]
        steps = sum(world.sim_steps for world in copies)
        for world in copies:
            world.close()
        return steps

    def close(self) -> None:
        for world in self.worlds:
            world.close()

    def get_images(self) -> Sequence[np.ndarray | None]:
        return [world.render() for world in self.worlds]

    def _targets(self, indices: VecEnvIndices) -> list[RobotEnv]:
        return [self.worlds[i] for i in self._get_indices(indices)]

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        return [getattr(world, attr_name) for world in self._targets(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        for world in self._targets(indices):
            setattr(world, attr_name, value)

    def env_method(
        self, method_name: str, *method_args: Any, indices: VecEnvIndices = None, **kwargs: Any
    ) -> list[Any]:
        return [
            getattr(world, method_name)(*method_args, **kwargs) for world in self._targets(indices)
        ]

    def env_is_wrapped(self, wrapper_class: type[Any], indices: VecEnvIndices = None) -> list[bool]:
        return [isinstance(world, wrapper_class) for world in self._targets(indices)]
