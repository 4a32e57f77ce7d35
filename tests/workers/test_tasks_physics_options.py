"""The options every task takes (issue 60): torque control, and randomising each
episode's mass, friction and motor strength, on PyBullet and MuJoCo, real engines both.
Each randomisation changes what the same actions do, the same seed draws the same
physics, and torques are bounded by each joint's effort (as this episode scales it)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from tests.workers import test_engines
from tests.workers.test_walk_forward import ACROSS

ENGINES = test_engines.ENGINES
engine_env = test_engines.engine_env
"""The fixture of tests/workers/test_engines.py: an env built as the worker builds it."""

EPISODE = 24


def trajectory(env, seed: int) -> np.ndarray:
    """The root's position after each control step of an episode in which every joint
    follows the gait clock (an inchworm's crawl: it slides, lifts and pushes)."""
    observation, _ = env.reset(seed=seed)
    positions = []
    for _ in range(EPISODE):
        clock = math.atan2(observation[-2], observation[-1])
        action = np.full(env.joint_count, math.sin(clock), dtype=np.float32)
        observation, *_ = env.step(action)
        positions.append(env.snapshot().position(0))
    return np.array(positions)


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize(
    "option",
    [{"mass_scale": [0.3, 0.5]}, {"friction": [0.05, 0.3]}, {"motor_strength": [0.2, 0.4]}],
    ids=["mass_scale", "friction", "motor_strength"],
)
def test_each_randomisation_changes_the_physics_and_the_seed_decides_it(
    engine_env, engine: str, option: dict[str, list[float]]
) -> None:
    # no joint noise: only the randomised physics differs between episodes
    plain = engine_env("walk-forward", ACROSS, engine, init_noise=0.0, episode_steps=EPISODE)
    drawn = engine_env(
        "walk-forward", ACROSS, engine, init_noise=0.0, episode_steps=EPISODE, **option
    )
    nominal = trajectory(plain, 0)
    assert np.array_equal(trajectory(plain, 1), nominal)  # without it the seed changes nothing
    first = trajectory(drawn, 0)
    assert np.abs(first - nominal).max() > 0.02  # the same actions moved it elsewhere
    assert np.array_equal(trajectory(drawn, 1 - 1), first)  # the same seed, the same physics
    assert np.abs(trajectory(drawn, 1) - first).max() > 0.01  # another seed, another draw
    # an episode after a randomised one, with nothing drawn, is back to the URDF's physics
    assert np.array_equal(trajectory(plain, 0), nominal)


@pytest.mark.parametrize("engine", ENGINES)
def test_torque_control_applies_the_action_times_the_effort_and_no_more(
    engine_env, engine: str
) -> None:
    arm = engine_env("diagonal-gesture", "crossed_chain", engine, control="torque", init_noise=0.0)
    efforts = np.array([joint.effort for joint in arm.robot.joints])
    meter = arm.meter_motors()
    arm.reset(seed=0)
    arm.step(np.array([0.5, -3.0], dtype=np.float32))  # the second beyond full torque
    assert arm.robot.applied_torques() == pytest.approx([0.5 * efforts[0], -efforts[1]])
    assert meter.energy > 0.0
    # a torque turns its joint that way, and goes on speeding it up while held
    first = arm.snapshot()
    assert first.q[0] > 0.0 and first.q[1] < 0.0
    arm.step(np.array([0.5, -1.0], dtype=np.float32))
    assert arm.snapshot().qd[0] > first.qd[0] > 0.0
    # weaker motors this episode: each torque scaled by its joint's drawn strength
    weak = engine_env(
        "diagonal-gesture", "crossed_chain", engine, control="torque", motor_strength=[0.2, 0.3]
    )
    weak.reset(seed=4)
    weak.step(np.array([1.0, 1.0], dtype=np.float32))
    scale = np.array(weak.robot.applied_torques()) / efforts
    assert np.all((scale >= 0.2 - 1e-9) & (scale <= 0.3 + 1e-9)), scale


DRAWN = {"mass_scale": [0.7, 1.3], "friction": [0.4, 1.6], "motor_strength": [0.6, 1.0]}
NEW_TASKS = {
    "track-velocity": "arch_chain",
    "reach-workspace": "crossed_chain",
    "carry-payload": "arch_chain",
}
"""Each new task on a design it takes: a free arch, or a fixed crossed arm."""


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize("task", sorted(NEW_TASKS))
def test_a_new_tasks_episodes_depend_only_on_seed_and_policy_its_physics_drawn(
    engine_env, task: str, engine: str
) -> None:
    env = engine_env(task, NEW_TASKS[task], engine, episode_steps=16, **DRAWN)

    def trace(action: list[float], seed: int) -> list[float]:
        env.reset(seed=seed)
        for _ in range(env.episode_steps):
            env.step(np.asarray(action, dtype=np.float32))
        return list(env.record.metric)

    first = trace([0.4, 0.4], seed=7)
    trace([-1.0, 1.0], seed=3)  # something else in between
    assert trace([0.4, 0.4], seed=7) == first
    assert trace([0.4, 0.4], seed=8) != first
