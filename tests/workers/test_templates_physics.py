"""A template's robot in real PyBullet and real MuJoCo (issues 28, 59): a task's
environment built from the URDF alone (no design) drives its revolute, prismatic and
continuous joints, holds its fixed ones, reads box, cylinder, sphere, capsule and
several-shape links where their origins put them, and sets a free robot down as built,
alike on both engines."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from adclient.builtin_tasks import DiagonalGestureOptions
from adclient.plugins import SimulatorOptions
from adclient.templates import expand
from adclient.urdf_model import read_urdf
from adworker.tasks.diagonal_gesture import DiagonalGesture
from adworker.tasks.lift_highest import LiftHighest

ARM = Path(__file__).resolve().parents[2] / "examples" / "templates" / "arm.urdf.xacro"
VALUES = {"upper_length": 0.2, "fore_length": 0.15, "hand_radius": 0.03}  # liftable

SLIDER = """<robot name="slider">
  <link name="post">
    <collision><geometry><box size="0.1 0.1 0.2"/></geometry></collision>
  </link>
  <link name="carriage">
    <inertial><mass value="0.5"/>{inertia}</inertial>
    <collision><geometry><box size="0.04 0.04 0.04"/></geometry></collision>
    <collision><origin xyz="0 0 0.1"/><geometry><sphere radius="0.03"/></geometry></collision>
  </link>
  <link name="wheel">
    <inertial><mass value="0.2"/>{inertia}</inertial>
    <collision>
      <origin rpy="1.5707963 0 0"/><geometry><capsule radius="0.02" length="0.1"/></geometry>
    </collision>
  </link>
  <joint name="lift" type="prismatic">
    <parent link="post"/><child link="carriage"/><origin xyz="0 0 0.1"/><axis xyz="0 0 1"/>
    <limit lower="0" upper="0.3" effort="50" velocity="1"/>
  </joint>
  <joint name="spin" type="continuous">
    <parent link="carriage"/><child link="wheel"/><origin xyz="0.05 0 0"/><axis xyz="1 0 0"/>
    <limit effort="5" velocity="10"/>
  </joint>
</robot>""".replace(
    "{inertia}", '<inertia ixx="0.001" ixy="0" ixz="0" iyy="0.001" iyz="0" izz="0.001"/>'
)


ENGINES = ("pybullet", "mujoco")


def _env(task, urdf: str, tmp_path: Path, options, simulator: str = "pybullet"):
    path = tmp_path / "robot.urdf"
    path.write_text(urdf)
    return task.make_env(design=None, urdf_path=path, options=options, simulator=simulator)


@pytest.mark.parametrize("engine", ENGINES)
def test_the_arm_template_is_built_from_its_urdf(tmp_path, engine: str) -> None:
    urdf = expand(ARM.read_text(), VALUES)
    model = read_urdf(urdf)
    env = _env(LiftHighest, urdf, tmp_path, SimulatorOptions(init_noise=0.0), engine)
    try:
        robot = env.robot
        assert [joint.name for joint in robot.joints] == ["shoulder", "elbow"]  # wrist: fixed
        assert robot.link_names == ["foot", "upper_arm", "forearm", "hand"]
        assert [g.kind for g in robot.geometry] == ["box", "cylinder", "cylinder", "sphere"]
        for g in robot.geometry:  # the engine's masses are the URDF's
            assert g.mass == pytest.approx(model.links[g.name].mass, rel=1e-9)
        env.reset(seed=0)
        snapshot = env.snapshot()
        # set down as built, lying along +x, its lowest point on the ground
        assert min(snapshot.bottom) == pytest.approx(1e-4, abs=1e-6)
        hand = robot.link_index("hand")
        assert snapshot.top[hand] == pytest.approx(snapshot.position(hand)[2] + 0.03, abs=1e-9)
        assert snapshot.position(hand)[0] == pytest.approx(0.08 + 0.2 + 0.15, abs=1e-3)
        # a rod along x: its long axis is the cylinder's, not its frame's z
        assert abs(snapshot.axis(robot.link_index("upper_arm"))[0]) == pytest.approx(1.0, abs=1e-3)
        rest = max(snapshot.top)
        for _ in range(60):  # shoulder up: the arm lifts what its motor can
            env.step(np.array([1.0, 0.0], dtype=np.float32))
        assert max(env.snapshot().top) > rest + 0.05
    finally:
        env.close()


def test_a_link_without_inertial_weighs_what_pybullet_simulates(tmp_path) -> None:
    """1 kg, PyBullet's default, in the model (so in the mass metric) and in the engine
    (a free robot: a fixed base is static, and PyBullet reports it as 0)."""
    assert read_urdf(SLIDER).links["post"].mass == 1.0
    env = _env(LiftHighest, SLIDER, tmp_path, SimulatorOptions())
    try:
        assert env.robot.geometry[env.robot.link_index("post")].mass == 1.0
    finally:
        env.close()


@pytest.mark.parametrize("engine", ENGINES)
def test_prismatic_continuous_capsule_and_several_shapes(tmp_path, engine: str) -> None:
    options = DiagonalGestureOptions(init_noise=0.0)
    env = _env(DiagonalGesture, SLIDER, tmp_path, options, engine)
    try:
        robot = env.robot
        assert [(j.name, j.lower, j.upper) for j in robot.joints] == [
            ("lift", 0.0, 0.3),
            ("spin", pytest.approx(-np.pi), pytest.approx(np.pi)),
        ]
        assert [g.kind for g in robot.geometry] == ["box", "compound", "capsule"]

        env.reset(seed=0)
        start = env.snapshot()
        carriage, wheel = robot.link_index("carriage"), robot.link_index("wheel")
        # the carriage's box and sphere: its top is the sphere's (0.1 + 0.03 above it)
        assert start.top[carriage] == pytest.approx(start.position(carriage)[2] + 0.13, abs=1e-6)
        # the capsule lies along y (turned by its origin): its ball reaches 0.02 below
        assert start.bottom[wheel] == pytest.approx(start.position(wheel)[2] - 0.02, abs=1e-6)
        for _ in range(40):  # lift to the top of the rail (metres), spin half round
            env.step(np.array([1.0, 0.5], dtype=np.float32))
        end = env.snapshot()
        assert end.q[0] == pytest.approx(0.3, abs=0.01)
        assert end.position(carriage)[2] - start.position(carriage)[2] == pytest.approx(
            0.3, abs=0.01
        )
        assert end.q[1] == pytest.approx(np.pi / 2, abs=0.05)
    finally:
        env.close()
