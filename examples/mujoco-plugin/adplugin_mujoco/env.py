"""mujoco-reach's environment: a Gymnasium env on MuJoCo that adworker's learners train.

adworker calls ``MujocoReach(design=, urdf_path=, options=)`` (the factory the
declaration names) and uses, besides Gymnasium's ``reset`` and ``step``:
``joint_count``; ``episode_steps``; ``gait_period`` (None: no gait clock); ``record``,
the episode's per-step ``metric`` and its ``score()``, and ``score_text``, that score in
words; ``sim_steps``;
``task_metrics()``, the task's own metrics of the episode just ended (the trial's
``task.tip_distance``); and ``render_image()`` for the trial's picture. Actions are
in [-1, 1] per joint and the observation starts with the joints' positions on the
same scale, so the ``fast`` learner's pose search and the stable-baselines3 learners
all work on it.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from adclient.designs import Design
from adplugin_mujoco import MujocoReachOptions
from adplugin_mujoco.mjcf import design_to_mjcf, driven_joints, joint_range

# Render off screen through EGL (no display needed), unless MUJOCO_GL says otherwise;
# MuJoCo reads it when first imported.
os.environ.setdefault("MUJOCO_GL", "egl")
import mujoco

log = logging.getLogger("adplugin_mujoco")

EPISODE_STEPS = 32
"""Control steps per episode unless ``options.episode_steps`` says otherwise (3.2 s)."""


@dataclass
class EpisodeRecord:
    metric: list[float] = field(default_factory=list)

    def score(self) -> float:
        """The mean metric over the episode's second half: the pose the arm holds."""
        half = self.metric[len(self.metric) // 2 :]
        return float(np.mean(half)) if half else 0.0


class MujocoReach(gym.Env[np.ndarray, np.ndarray]):
    """One design in its own MuJoCo model; the metric is minus the tip's distance to
    the target (m). Observation: joint positions in [-1, 1], joint velocities, and the
    tip's offset from the target."""

    score_text = "the per-step metric's second-half mean"
    """What ``record.score()`` is, in words: the trial's ``curve.json`` says it."""

    metadata = {"render_modes": ["rgb_array"]}

    def __init__(
        self,
        *,
        design: Design,
        urdf_path: str | Path,  # unused: the model is built from the design itself
        options: MujocoReachOptions,
        render_mode: str | None = None,
    ) -> None:
        super().__init__()
        self.options = options
        self.render_mode = render_mode
        self.target = np.array(options.target)
        xml = design_to_mjcf(design, time_step=options.time_step, target=options.target)
        self.model = mujoco.MjModel.from_xml_string(xml)
        self.data = mujoco.MjData(self.model)
        self.tip = self.data.site(f"{options.tip_link}_end")
        driven = driven_joints(design)
        names = [joint.name for joint in driven]
        self.qpos = np.array([self.model.joint(name).qposadr[0] for name in names])
        self.qvel = np.array([self.model.joint(name).dofadr[0] for name in names])
        lower, upper = np.array([joint_range(joint) for joint in driven]).T
        self.mid, self.half = (upper + lower) / 2, (upper - lower) / 2
        self.speed = np.array([joint.velocity for joint in driven])

        self.joint_count = len(names)
        self.episode_steps = options.episode_steps or EPISODE_STEPS
        self.gait_period: float | None = None
        self.sim_steps = 0
        self.record = EpisodeRecord()
        self.action_space = gym.spaces.Box(-1.0, 1.0, (self.joint_count,), np.float32)
        size = 2 * self.joint_count + 3
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (size,), np.float32)
        self._steps = 0
        self._renderer: Any = None

    def _observe(self) -> np.ndarray:
        q = (self.data.qpos[self.qpos] - self.mid) / self.half
        qd = self.data.qvel[self.qvel] / self.speed
        return np.concatenate([q, qd, self.tip.xpos - self.target]).astype(np.float32)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        mujoco.mj_resetData(self.model, self.data)
        noise = self.np_random.uniform(-1, 1, self.joint_count) * self.options.init_noise
        start = np.clip(noise, self.mid - self.half, self.mid + self.half)
        self.data.qpos[self.qpos] = start
        self.data.ctrl[:] = start  # the servos hold the starting pose
        mujoco.mj_forward(self.model, self.data)
        self.record = EpisodeRecord()
        self._steps = 0
        return self._observe(), {}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        self.data.ctrl[:] = self.mid + np.clip(action, -1.0, 1.0) * self.half
        mujoco.mj_step(self.model, self.data, nstep=self.options.frame_skip)
        self.sim_steps += self.options.frame_skip
        self._steps += 1
        metric = -float(np.linalg.norm(self.tip.xpos - self.target))
        self.record.metric.append(metric)
        truncated = self._steps >= self.episode_steps
        info = {"score": self.record.score()} if truncated else {}
        return self._observe(), metric, False, truncated, info

    def task_metrics(self) -> dict[str, float]:
        """The tip's distance to the target (m) at the end of the episode."""
        return {"tip_distance": float(np.linalg.norm(self.tip.xpos - self.target))}

    def render(self) -> np.ndarray | None:
        return self.render_image() if self.render_mode == "rgb_array" else None

    def render_image(self, width: int = 320, height: int = 240) -> np.ndarray:
        """The current pose from the side, the target a small sphere."""
        camera = mujoco.MjvCamera()
        camera.lookat[:] = (0.1, 0.1, 0.6)
        camera.distance, camera.azimuth, camera.elevation = 2.8, 135.0, -15.0
        try:
            if self._renderer is None:
                self._renderer = mujoco.Renderer(self.model, height, width)
            self._renderer.update_scene(self.data, camera=camera)
            return np.asarray(self._renderer.render())
        except Exception as error:  # no OpenGL here: a blank picture, not a failed trial
            log.warning("MuJoCo cannot render here (%s); the picture is blank", error)
            return np.full((height, width, 3), 255, dtype=np.uint8)

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        super().close()
