"""Which engine builds a task's world: the simulator and the robot of the engine a study
names (``task.simulator``), behind the interface of :mod:`adworker.tasks.engine`."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from adclient.plugins import SIMULATORS
from adworker.tasks.engine import EngineRobot, EngineSimulator, PayloadSpec
from adworker.tasks.model import RobotModel


def build_engine(
    simulator: str,
    *,
    model: RobotModel,
    urdf_path: str | Path,
    fixed_base: bool,
    reads_contacts: bool,
    time_step: float,
    frame_skip: int,
    rolling_friction: float,
    spinning_friction: float,
    control: str = "position",
    payload: PayloadSpec | None = None,
) -> tuple[EngineSimulator, EngineRobot]:
    """A simulator of the engine ``simulator`` (one of ``adclient.plugins.SIMULATORS``)
    with the robot of ``model`` (its URDF at ``urdf_path``) in it; ValueError naming an
    engine that is not one. The engine's module is imported here, on first use.
    ``control`` is what an action commands (``position`` or ``torque``); ``payload``, a
    box the robot carries."""
    sim: EngineSimulator
    if simulator == "pybullet":
        from adworker.tasks.robot import Robot
        from adworker.tasks.simulator import Simulator

        sim = Simulator(time_step=time_step, frame_skip=frame_skip)
        robot_class: Any = Robot
    elif simulator == "mujoco":
        from adworker.tasks.mujoco_engine import MujocoRobot, MujocoSimulator

        sim = MujocoSimulator(time_step=time_step, frame_skip=frame_skip)
        robot_class = MujocoRobot
    else:
        raise ValueError(f"simulator {simulator!r} is not one ({', '.join(SIMULATORS)})")
    try:
        robot = robot_class(
            sim,
            model,
            urdf_path,
            fixed_base=fixed_base,
            reads_contacts=reads_contacts,
            rolling_friction=rolling_friction,
            spinning_friction=spinning_friction,
            control=control,
            payload=payload,
        )
    except BaseException:
        sim.close()
        raise
    return sim, robot
