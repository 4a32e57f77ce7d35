"""carry-payload (issue 60): a box resting on a link of a free robot, on PyBullet and
MuJoCo, real bodies both. A robot that holds still keeps it and scores nothing; an arch
that lifts it scores its rise; one that throws it to the ground has dropped it and
scores no progress, whatever ground the box covered."""

from __future__ import annotations

import numpy as np
import pytest

from tests.workers import test_engines

ENGINES = test_engines.ENGINES
engine_env = test_engines.engine_env
"""The fixture of tests/workers/test_engines.py: an env built as the worker builds it."""

LIFT = {"payload_link": "b", "direction": "up", "episode_steps": 40}
"""A box on the middle link of the stand-up arch, progress counted up."""


def episode(env, actions) -> float:
    env.reset(seed=0)
    for t in range(env.episode_steps):
        env.step(np.asarray(actions(t), dtype=np.float32))
    return env.record.score()


@pytest.mark.parametrize("engine", ENGINES)
def test_holding_lifting_and_dropping_the_payload(engine_env, engine: str) -> None:
    # light and wide, so the springier arch of MuJoCo's servos holds it too
    arch = engine_env(
        "carry-payload", "arch_chain", engine, payload_mass=0.01, payload_size=0.1, **LIFT
    )
    start = arch.robot.payload_state()
    assert start.position[2] > arch.snapshot().top[1]  # it rests on b, above it

    still = episode(arch, lambda t: [0.0, 0.0])
    assert abs(still) < 0.01
    assert arch.task_metrics() == {"fell": 0.0, "dropped": 0.0}
    assert arch.robot.payload_state().on_robot

    lifted = episode(arch, lambda t: [0.5, 0.5])  # the arch folds up under it
    assert arch.task_metrics()["dropped"] == 0.0
    assert lifted > 0.2
    assert lifted == pytest.approx(arch.robot.payload_state().position[2] - start.position[2])

    # every joint thrown end to end: the box flies off and lands on the ground
    thrown = episode(arch, lambda t: [1.0, 1.0] if (t // 2) % 2 == 0 else [-1.0, -1.0])
    assert arch.task_metrics()["dropped"] == 1.0
    assert thrown <= 0.0
    assert arch.record.metric[-1] == thrown
