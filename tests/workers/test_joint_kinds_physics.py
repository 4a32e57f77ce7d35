"""Joint kinds and capsules of a design in real PyBullet (issue 28): a prismatic joint
slides its child along its axis to its limits in metres, a continuous one turns past
any revolute range, a fixed one holds its child and takes no action, and a capsule's
ends reach its radius past the link."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from adclient.builtin_tasks import DiagonalGestureOptions
from adclient.decode import decode, identity_representation, spec_layout
from adclient.design import DesignSpace
from adclient.urdf import design_to_urdf
from adworker.tasks.base import RobotEnv
from adworker.tasks.diagonal_gesture import DiagonalGesture

SPACE = {
    "type": "design",
    "parts": {
        "post": {"shape": "box", "length": 0.2, "radius": 0.05, "mass": {"low": 1.0, "high": 2.0}},
        "rod": {"shape": "capsule", "length": 0.2, "radius": 0.02, "density": 1000.0},
    },
    "joint": {"axis_theta": 0.0, "axis_phi": 0.0, "effort": 50.0, "velocity": 2.0},
    "instances": [
        {"name": "a", "part": "post"},
        {
            "name": "b",
            "part": "rod",
            "joint_type": "prismatic",
            "joint_overrides": {"lower": 0.0, "upper": 0.15},
        },
        {
            "name": "c",
            "part": "rod",
            "joint_type": "continuous",
            "joint_overrides": {"axis_theta": 1.5707963267948966},
        },
        {"name": "d", "part": "rod", "joint_type": "fixed"},
    ],
    "structures": [[["a", "b"], ["b", "c"], ["c", "d"]]],
}


def _env(space: DesignSpace, tmp_path: Path) -> RobotEnv:
    """diagonal-gesture's environment (a fixed base) for the space's design at [0]."""
    design = decode(space, identity_representation(space), [0.0])
    path = tmp_path / "robot.urdf"
    path.write_text(design_to_urdf(design))
    return DiagonalGesture.make_env(
        design=design, urdf_path=path, options=DiagonalGestureOptions(init_noise=0.0)
    )


def test_prismatic_continuous_and_fixed_joints_of_a_design(tmp_path) -> None:
    space = DesignSpace.model_validate(SPACE)
    assert spec_layout(space).names == ["a.mass"]  # a fixed joint, a continuous one: no limits
    env = _env(space, tmp_path)
    try:
        robot = env.robot
        assert [(j.name, j.lower, j.upper) for j in robot.joints] == [
            ("a_b", 0.0, 0.15),
            ("b_c", -math.pi, math.pi),
        ]  # c_d is fixed: no action
        assert env.action_space.shape == (2,)
        assert [g.kind for g in robot.geometry] == ["box", "capsule", "capsule", "capsule"]
        env.reset(seed=0)
        start = env.snapshot()
        b, d = robot.link_index("b"), robot.link_index("d")
        # a capsule's ball reaches its radius past its ends: b starts at the post's top
        assert start.bottom[b] == pytest.approx(0.2 - 0.02, abs=1e-6)
        assert start.top[d] == pytest.approx(0.2 + 3 * 0.2 + 0.02, abs=1e-6)
        for _ in range(40):  # slide up the whole rail, turn c to 3/4 of pi
            env.step(np.array([1.0, 0.75], dtype=np.float32))
        end = env.snapshot()
        assert end.q[0] == pytest.approx(0.15, abs=0.005)
        assert end.position(b)[2] - start.position(b)[2] == pytest.approx(0.15, abs=0.005)
        assert end.q[1] == pytest.approx(0.75 * math.pi, abs=0.05)  # past a revolute's pi/2
        # d is held to c: it turned with it, rigidly
        assert end.axis(d) == pytest.approx(end.axis(robot.link_index("c")), abs=1e-6)
    finally:
        env.close()


def test_an_offset_turns_the_child_at_rest(tmp_path) -> None:
    """A quarter roll on the joint: at rest the child's long axis leaves the post
    sideways (world y), not upwards."""
    body = {
        **SPACE,
        "instances": [
            {"name": "a", "part": "post"},
            {"name": "b", "part": "rod", "joint_overrides": {"offset_roll": -math.pi / 2}},
        ],
        "structures": [[["a", "b"]]],
    }
    space = DesignSpace.model_validate(body)
    env = _env(space, tmp_path)
    try:
        env.reset(seed=0)
        snapshot = env.snapshot()
        b = env.robot.link_index("b")
        assert snapshot.axis(b) == pytest.approx((0.0, 1.0, 0.0), abs=1e-6)
        assert snapshot.axis(env.robot.link_index("a")) == pytest.approx((0.0, 0.0, 1.0))
    finally:
        env.close()
