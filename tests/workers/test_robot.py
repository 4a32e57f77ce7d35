"""The simulator and the robot apart from any task: the robot is the Design, and the
engine's answers are read by the names given to their positions."""

from __future__ import annotations

import numpy as np
import pybullet
import pytest

from adclient.designs import Link
from adclient.spawn import CLEARANCE, design_model
from adworker import designs
from adworker.tasks.model import model_of_design
from adworker.tasks.robot import Robot
from adworker.tasks.simulator import CONTACT_DISTANCE, CONTACT_LINK_A, JointInfo, Simulator
from tests.workers.robots import write_urdf

STAR = designs.tree_design(
    [("a", "b"), ("a", "c"), ("c", "d")],
    {"b": (1.1, 0.3), "c": (0.4, 2.0), "d": (2.5, 1.2)},
    length={"a": 0.5, "b": 0.3, "c": 0.45, "d": 0.25},
    position={"b": 1.0, "c": 0.5, "d": 1.0},
)


@pytest.fixture
def sim():
    simulator = Simulator(time_step=1 / 120, frame_skip=12)
    yield simulator
    simulator.close()


def _robot(sim: Simulator, design, path) -> Robot:
    return Robot(
        sim,
        model_of_design(design),
        write_urdf(design, path),
        fixed_base=False,
        reads_contacts=True,
        rolling_friction=0.02,
        spinning_friction=0.0,
    )


def test_the_robot_is_its_design(sim, tmp_path) -> None:
    robot = _robot(sim, STAR, tmp_path / "star.urdf")
    assert robot.link_names[0] == STAR.root
    assert sorted(robot.link_names) == sorted(link.name for link in STAR.links)
    by_name = {joint.name: joint for joint in STAR.joints}
    unit_axes = {joint.name: joint.axis for joint in design_model(STAR).joints}
    assert sorted(joint.name for joint in robot.joints) == sorted(by_name)
    for joint in robot.joints:
        designed = by_name[joint.name]
        info = sim.joint_info(robot.body, joint.index)
        assert info.name.decode() == joint.name
        assert info.link_name.decode() == joint.child == designed.child
        assert robot.link_names[robot.link_index(joint.child)] == joint.child
        parent = info.parent_index
        assert (
            STAR.root if parent == -1 else sim.joint_info(robot.body, parent).link_name.decode()
        ) == designed.parent
        assert info.axis == pytest.approx(unit_axes[joint.name], abs=1e-12)
        assert (
            (joint.lower, joint.upper)
            == (designed.lower, designed.upper)
            == (info.lower, info.upper)
        )
        assert (joint.effort, joint.velocity) == (info.max_force, info.max_velocity)
    lengths = {link.name: link.length for link in STAR.links}
    for g in robot.geometry:
        assert g.length == lengths[g.name]
        # The URDF's inertial frame sits at the shape's centre: the ends lie at +-length/2.
        assert g.points[:, 2] == pytest.approx([-g.length / 2, g.length / 2])
        assert g.centre == pytest.approx([0.0, 0.0, 0.0])


def test_joints_whose_range_leaves_out_zero_start_at_their_nearest_limit(sim, tmp_path) -> None:
    """An episode starts each joint at 0 clipped to its range, plus noise: the robot is
    set down in that pose (``adclient.spawn``), its lowest point just off the ground."""
    bent = designs.arch_chain()
    bent = bent.model_copy(
        update={
            "joints": [
                bent.joints[0].model_copy(update={"lower": 0.4, "upper": 1.2}),
                bent.joints[1].model_copy(update={"lower": -1.0, "upper": -0.3}),
            ]
        }
    )
    robot = _robot(sim, bent, tmp_path / "bent.urdf")
    assert robot.spawn.joints == {bent.joints[0].name: 0.4, bent.joints[1].name: -0.3}
    states = pybullet.getJointStates(robot.body, robot.joint_indices, physicsClientId=sim.client)
    assert [state[0] for state in states] == [0.4, -0.3]
    assert min(robot.read().bottom) == pytest.approx(CLEARANCE, abs=1e-7)
    reset = robot.reset(np.zeros(2))
    assert reset.q == pytest.approx([0.4, -0.3])
    assert min(reset.bottom) == pytest.approx(CLEARANCE, abs=1e-7)


def test_joint_info_names_every_position_pybullet_answers(sim, tmp_path) -> None:
    robot = _robot(sim, STAR, tmp_path / "star.urdf")
    raw = pybullet.getJointInfo(robot.body, 2, physicsClientId=sim.client)
    named = sim.joint_info(robot.body, 2)
    assert len(raw) == len(JointInfo._fields)
    assert named.joint_index == 2
    assert named.type == pybullet.JOINT_REVOLUTE
    assert named.parent_index == robot.joints[1].index  # d hangs off c


def test_a_urdf_of_another_design_is_refused(sim, tmp_path) -> None:
    write_urdf(designs.arch_chain(), tmp_path / "arch.urdf")
    with pytest.raises(ValueError, match="not the model's"):
        Robot(
            sim,
            model_of_design(STAR),
            tmp_path / "arch.urdf",
            fixed_base=False,
            reads_contacts=True,
            rolling_friction=0.0,
            spinning_friction=0.0,
        )


def test_contacts_are_read_by_their_named_positions(sim, tmp_path) -> None:
    robot = _robot(sim, designs.arch_chain(), tmp_path / "arch.urdf")
    robot.reset(np.zeros(robot.joint_count))
    sim.step()  # the engine finds contacts as it steps
    lying = robot.read()
    assert lying.touching == [True, True, True]  # laid on the ground along +x
    contacts = sim.ground_contacts(robot.body)
    assert {contact[CONTACT_LINK_A] for contact in contacts} == {-1, 0, 1}
    assert all(abs(contact[CONTACT_DISTANCE]) < 1e-3 for contact in contacts)
    assert lying.centre_z == pytest.approx([0.04, 0.04, 0.04], abs=1e-3)
    pybullet.resetBasePositionAndOrientation(
        robot.body, [0, 0, 1.0], [0, 0, 0, 1], physicsClientId=sim.client
    )
    sim.step()
    assert robot.read().touching == [False, False, False]


def test_box_links_take_their_shape_from_the_design(sim, tmp_path) -> None:
    design = designs.arch_chain()
    design.links[1] = Link(name="b", shape="box", length=0.4, radius=0.05, mass=1.0)
    robot = _robot(sim, design, tmp_path / "box.urdf")
    b = robot.link_index("b")
    assert robot.geometry[b].kind == "box"
    assert len(robot.geometry[b].points) == 8
    snapshot = robot.read()
    # The chain lies along +x with a cylinder of radius 0.04 at each end: the box sits
    # 2 x 0.05 tall, its bottom no lower than the ground.
    assert snapshot.top[b] - snapshot.bottom[b] == pytest.approx(0.1, abs=1e-6)
    assert min(snapshot.bottom) == pytest.approx(0.0, abs=2e-4)


def test_a_simulator_steps_saves_and_restores(sim, tmp_path) -> None:
    robot = _robot(sim, designs.arch_chain(), tmp_path / "arch.urdf")
    assert sim.control_period == pytest.approx(0.1)

    def run() -> list[float]:
        robot.reset(np.zeros(robot.joint_count))
        heights = []
        for _ in range(5):
            robot.act(np.array([0.7, 0.7], dtype=np.float32))
            sim.step()
            heights.append(robot.read().centre_z[1])
        return heights

    first = run()
    assert sim.physics_steps == 5 * sim.frame_skip
    assert max(first) > 0.1  # b rises as the arch folds
    assert run() == first  # reset restores the saved state exactly
    sim.close()
    assert not sim.connected


def _energy(sim: Simulator, robot: Robot) -> float:
    """Kinetic (of the centres of mass) plus potential energy of the robot (J)."""
    cid, body = sim.client, robot.body
    linear = [pybullet.getBaseVelocity(body, physicsClientId=cid)[0]]
    heights = [pybullet.getBasePositionAndOrientation(body, physicsClientId=cid)[0][2]]
    links = [g.index for g in robot.geometry if g.index >= 0]
    for state in pybullet.getLinkStates(
        body, links, computeLinkVelocity=1, computeForwardKinematics=1, physicsClientId=cid
    ):
        linear.append(state[6])
        heights.append(state[0][2])
    masses = [g.mass for g in robot.geometry]
    return sum(
        m * (0.5 * sum(v * v for v in velocity) + 9.81 * z)
        for m, velocity, z in zip(masses, linear, heights, strict=True)
    )


def test_a_free_robot_gains_no_energy_its_motors_did_not_give(sim, tmp_path) -> None:
    """Joints swinging fast and hard: the body's energy stays within the motors' work,
    and every joint within its speed limit (set once, kept across resets and commands).
    The old velocity clamp on the whole body (maxJointVelocity) failed it: 31 J of 78."""
    design = designs.tree_design(
        [("a", "b"), ("b", "c"), ("c", "d")],
        {"b": (2.17, 0.02), "c": (0.56, 0.82), "d": (1.24, 1.32)},
        effort=4.0,
        velocity=3.0,
    )
    robot = _robot(sim, design, tmp_path / "chain.urdf")
    for episode in range(2):
        robot.reset(np.zeros(robot.joint_count))
        start, work, fastest, surplus = _energy(sim, robot), 0.0, 0.0, 0.0
        for step in range(24):
            swing = 1.0 if (step // 3 + episode) % 2 == 0 else -1.0
            robot.act(np.array([swing, -swing, swing], dtype=np.float32))
            for _ in range(sim.frame_skip):
                pybullet.stepSimulation(physicsClientId=sim.client)
                states = pybullet.getJointStates(
                    robot.body, robot.joint_indices, physicsClientId=sim.client
                )
                work += sim.time_step * sum(abs(s[1] * s[3]) for s in states)
                fastest = max(fastest, *(abs(s[1]) for s in states))
            surplus = max(surplus, _energy(sim, robot) - start - work)
        assert work > 5.0  # the motors did work hard
        assert surplus < 0.05 * work, (surplus, work)
        assert fastest < 3.3  # the motor holds it to its limit, give or take an impact


def test_what_docs_plugins_md_says_a_task_reads_is_so(sim, tmp_path) -> None:
    """The task API table of docs/plugins.md (issue 39): every name it lists exists, and
    its meanings hold in PyBullet: position is the centre of mass, axis runs from the
    parent end to the tip, and a design link's tip is centre + axis * length / 2."""
    import re
    from pathlib import Path

    robot = _robot(sim, STAR, tmp_path / "star.urdf")
    snapshot = robot.reset(np.zeros(robot.joint_count))
    for _ in range(5):
        robot.act(np.array([0.6, -0.4, 0.8])[: robot.joint_count])
        sim.step()
    snapshot = robot.read()

    docs = (Path(__file__).resolve().parents[2] / "docs" / "plugins.md").read_text()
    table = docs[docs.index("What a task reads") : docs.index("A link's tip, for a design")]
    named = set(re.findall(r"`(robot|snapshot)\.(\w+)", table))
    assert len(named) >= 15
    for owner, name in named:
        assert hasattr(robot if owner == "robot" else snapshot, name), f"{owner}.{name}"
    for name in ("kind", "length", "radius", "mass", "centre", "axis"):
        assert hasattr(robot.geometry[0], name)

    cid = sim.client
    for link in ("b", "c", "d"):
        k = robot.link_index(link)
        index = robot.geometry[k].index
        state = pybullet.getLinkState(
            robot.body, index, computeForwardKinematics=1, physicsClientId=cid
        )
        com, frame_position, frame_orientation = state[0], state[4], state[5]
        assert snapshot.position(k) == pytest.approx(com, abs=1e-9)
        rotation = np.array(pybullet.getMatrixFromQuaternion(frame_orientation)).reshape(3, 3)
        length = robot.geometry[k].length
        parent_end = np.array(frame_position)
        tip = parent_end + rotation @ np.array([0.0, 0.0, length])
        centre = np.asarray(snapshot.centre(k))
        axis = np.asarray(snapshot.axis(k))
        assert np.linalg.norm(axis) == pytest.approx(1.0)
        assert centre + axis * length / 2 == pytest.approx(tip, abs=1e-6)
        assert centre - axis * length / 2 == pytest.approx(parent_end, abs=1e-6)
        assert snapshot.top[k] >= max(tip[2], parent_end[2]) - 1e-9
        assert snapshot.bottom[k] <= min(tip[2], parent_end[2]) + 1e-9
    with pytest.raises(KeyError, match="no link named 'nope'"):
        robot.link_index("nope")


def test_link_position_is_a_deprecated_alias_of_link_index(sim, tmp_path) -> None:
    """The old name returned an index, not a position: it still works for one release,
    with a DeprecationWarning naming the new one."""
    robot = _robot(sim, designs.arch_chain(), tmp_path / "arch.urdf")
    with pytest.warns(DeprecationWarning, match="use Robot.link_index"):
        assert robot.link_position("b") == robot.link_index("b") == 1
