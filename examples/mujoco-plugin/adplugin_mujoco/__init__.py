"""The declaration of mujoco-reach: light (no MuJoCo), so a server reads it to check
study files. Only the worker imports the environment (adplugin_mujoco.env)."""

from __future__ import annotations

from pydantic import Field

from adclient.plugins import TaskOptions, TaskSpec


class MujocoReachOptions(TaskOptions):
    """Not adworker's PyBullet simulator, so TaskOptions (episode_steps, learner_kwargs)
    plus this task's own physics settings."""

    tip_link: str = Field(default="c", min_length=1, description="The link whose far end reaches")
    target: tuple[float, float, float] = Field(
        default=(0.3, 0.3, 0.6), description="The point to reach (m), in the world frame"
    )
    time_step: float = Field(default=0.005, gt=0.0, le=0.05, description="MuJoCo's time step (s)")
    frame_skip: int = Field(default=20, ge=1, le=1000, description="Physics steps per action")
    init_noise: float = Field(
        default=0.05, ge=0.0, le=3.2, description="Largest random joint offset at reset (rad)"
    )

    def link_names(self) -> list[tuple[str, str]]:
        return [("tip_link", self.tip_link)]


MUJOCO_REACH = TaskSpec(
    name="mujoco-reach",
    options=MujocoReachOptions,
    description="MuJoCo: an arm on a fixed base brings the far end of its tip link to a "
    "target point: minus the distance (m), averaged over the episode's second half.",
    factory="adplugin_mujoco.env:MujocoReach",
    fixed_base=True,
)
