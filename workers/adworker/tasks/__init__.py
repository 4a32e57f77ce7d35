"""The built-in tasks, by name: Gymnasium envs built from a URDF path and options."""

from __future__ import annotations

from adworker.tasks.base import RobotEnv, episode_score
from adworker.tasks.diagonal_gesture import DiagonalGestureEnv
from adworker.tasks.lift_highest import LiftHighestEnv
from adworker.tasks.stand_up import StandUpEnv

TASKS: dict[str, type[RobotEnv]] = {
    StandUpEnv.task_name: StandUpEnv,
    DiagonalGestureEnv.task_name: DiagonalGestureEnv,
    LiftHighestEnv.task_name: LiftHighestEnv,
}


class UnknownTask(KeyError):
    """The job names a task this worker does not have."""


def get_task(name: str) -> type[RobotEnv]:
    """The env class of a task; raises UnknownTask naming the ones there are."""
    try:
        return TASKS[name]
    except KeyError:
        raise UnknownTask(
            f"unknown task {name!r}; known tasks: {', '.join(sorted(TASKS))}"
        ) from None


__all__ = ["TASKS", "RobotEnv", "UnknownTask", "episode_score", "get_task"]
