"""URDF writer: every generated URDF loads in PyBullet (DIRECT) and matches its design."""

from __future__ import annotations

import itertools
import math
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pybullet
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from adclient.decode import decode, identity_representation
from adclient.design import DesignSpace
from adclient.designs import Design, Joint, Link
from adclient.urdf import URDFError, design_mass, design_to_urdf, link_inertia
from tests.client.design_strategies import single_structure_spaces

_COUNTER = itertools.count()
FLAGS = pybullet.URDF_USE_INERTIA_FROM_FILE | pybullet.URDF_USE_IMPLICIT_CYLINDER


@pytest.fixture(scope="module")
def client() -> Iterator[int]:
    cid = pybullet.connect(pybullet.DIRECT)
    yield cid
    pybullet.disconnect(physicsClientId=cid)


def load(client: int, urdf: str, path: Path) -> int:
    """Load from a fresh file name: PyBullet caches files by name within a client."""
    path = path.with_name(f"{path.stem}-{next(_COUNTER)}.urdf")
    path.write_text(urdf)
    pybullet.resetSimulation(physicsClientId=client)
    return pybullet.loadURDF(str(path), flags=FLAGS, physicsClientId=client)


def check_matches(client: int, body: int, design: Design) -> None:
    links = {link.name: link for link in design.links}
    assert pybullet.getBodyInfo(body, physicsClientId=client)[0].decode() == design.root
    assert pybullet.getNumJoints(body, physicsClientId=client) == len(design.joints)
    index_of = {design.root: -1}
    joints = {joint.name: joint for joint in design.joints}
    for index in range(len(design.joints)):
        info = pybullet.getJointInfo(body, index, physicsClientId=client)
        joint = joints[info[1].decode()]
        index_of[info[12].decode()] = index
        assert info[12].decode() == joint.child
        assert info[2] == pybullet.JOINT_REVOLUTE
        assert info[8] == pytest.approx(joint.lower) and info[9] == pytest.approx(joint.upper)
        assert info[10] == pytest.approx(joint.effort)
        assert info[11] == pytest.approx(joint.velocity)
        assert info[13] == pytest.approx(joint.axis, abs=1e-9)
        # the joint sits at position * parent.length; PyBullet measures from the
        # parent's centre of mass, which is at half its length
        parent = links[joint.parent]
        expected_z = joint.position * parent.length - parent.length / 2
        assert info[14] == pytest.approx((0.0, 0.0, expected_z), abs=1e-9)
        assert info[16] == index_of[joint.parent]  # the parent was listed before
    assert set(index_of) == set(links)
    for name, index in index_of.items():
        link = links[name]
        dynamics = pybullet.getDynamicsInfo(body, index, physicsClientId=client)
        assert dynamics[0] == pytest.approx(link.mass)
        assert dynamics[2] == pytest.approx(link_inertia(link), rel=1e-6)
        (collision,) = pybullet.getCollisionShapeData(body, index, physicsClientId=client)
        if link.shape == "cylinder":
            assert collision[2] == pybullet.GEOM_CYLINDER
            assert collision[3][:2] == pytest.approx((link.length, link.radius))
        else:
            assert collision[2] == pybullet.GEOM_BOX
            side = 2 * link.radius
            assert collision[3] == pytest.approx((side, side, link.length))
    visuals = pybullet.getVisualShapeData(body, physicsClientId=client)
    assert len(visuals) == len(links)
    for visual in visuals:
        name = (
            design.root
            if visual[1] == -1
            else next(k for k, v in index_of.items() if v == visual[1])
        )
        # the shape spans [0, length] along the link frame's z axis
        assert visual[5] == pytest.approx((0.0, 0.0, links[name].length / 2))


@settings(
    max_examples=40,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)
@given(single_structure_spaces(max_links=6), st.data())
def test_generated_urdf_loads_and_matches(
    client: int, tmp_path: Path, body: dict[str, Any], data: st.DataObject
) -> None:
    space = DesignSpace.model_validate(body)
    representation = identity_representation(space)
    size = len(representation.spec_names)
    vector = data.draw(st.lists(st.floats(0.0, 1.0), min_size=size, max_size=size))
    design = decode(space, representation, vector)
    urdf = design_to_urdf(design, robot_name="generated")
    root = ET.fromstring(urdf.split("\n", 1)[1])
    assert root.tag == "robot" and root.get("name") == "generated"
    assert len(root.findall("link")) == len(design.links)
    assert len(root.findall("joint")) == len(design.joints)
    body_id = load(client, urdf, tmp_path / "robot.urdf")
    check_matches(client, body_id, design)


def chain(names: tuple[str, str] = ("a", "b"), joint_name: str = "a_b", **link: float) -> Design:
    child = {"length": 0.3, "radius": 0.03, "mass": 0.5} | link
    links = [
        Link(name=names[0], shape="cylinder", length=0.4, radius=0.04, mass=1.0),
        Link(name=names[1], shape="cylinder", **child),
    ]
    joint = Joint(
        name=joint_name,
        parent=names[0],
        child=names[1],
        axis=(0.0, 1.0, 0.0),
        axis_theta=math.pi / 2,
        axis_phi=math.pi / 2,
        position=1.0,
        lower=-1.0,
        upper=1.0,
        effort=10.0,
        velocity=2.0,
    )
    return Design(structure_index=0, root=names[0], links=links, joints=[joint])


@pytest.mark.parametrize(
    "bad",
    ['a"b', "a<b>", "x&y", "a b", "", "1abc", "a/../b", "\u00e9t\u00e9", "a\nb", "a" * 65],
)
def test_odd_names_are_rejected(bad: str) -> None:
    with pytest.raises(URDFError, match="is not allowed"):
        design_to_urdf(chain(names=(bad, "b"), joint_name="j"))
    with pytest.raises(URDFError, match="is not allowed"):
        design_to_urdf(chain(joint_name=bad))
    with pytest.raises(URDFError, match="robot name"):
        design_to_urdf(chain(), robot_name=bad)


def test_allowed_names_survive_the_xml(client: int, tmp_path: Path) -> None:
    design = chain(names=("Base_link-1", "arm-2_x"), joint_name="Base_link-1_arm-2_x")
    urdf = design_to_urdf(design, robot_name="robot-Name_1")
    body = load(client, urdf, tmp_path / "named.urdf")
    check_matches(client, body, design)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"length": -0.1}, "length must be > 0"),
        ({"radius": 0.0}, "radius must be > 0"),
        ({"mass": math.nan}, "mass must be a finite number"),
    ],
)
def test_bad_numbers_are_rejected(change: dict[str, float], message: str) -> None:
    with pytest.raises(URDFError, match=message):
        design_to_urdf(chain(("a", "b"), "a_b", **change))


def test_bad_trees_are_rejected() -> None:
    design = chain()
    loop = design.model_copy(
        update={
            "joints": [
                *design.joints,
                design.joints[0].model_copy(update={"name": "b_a", "parent": "b", "child": "a"}),
            ]
        }
    )
    with pytest.raises(URDFError, match=r"not one tree|two parent"):
        design_to_urdf(loop)
    orphan = design.model_copy(update={"joints": []})
    with pytest.raises(URDFError, match="not one tree"):
        design_to_urdf(orphan)
    dangling = design.model_copy(
        update={"joints": [design.joints[0].model_copy(update={"child": "c"})]}
    )
    with pytest.raises(URDFError, match="unknown link 'c'"):
        design_to_urdf(dangling)
    still = design.model_copy(
        update={"joints": [design.joints[0].model_copy(update={"axis": (0.0, 0.0, 0.0)})]}
    )
    with pytest.raises(URDFError, match="has no direction"):
        design_to_urdf(still)


def test_a_density_links_urdf_carries_its_derived_mass_and_inertia(
    client: int, tmp_path: Path
) -> None:
    """A part that gives density: the URDF's inertial mass is density x volume and the
    inertia tensor that of a solid cylinder (or box) of that mass, as PyBullet loads it;
    design_mass sums the derived masses."""
    space = DesignSpace.model_validate(
        {
            "type": "design",
            "parts": {
                "link": {
                    "length": {"low": 0.2, "high": 0.6},
                    "radius": {"low": 0.01, "high": 0.05},
                    "density": 2700.0,
                },
                "plate": {"shape": "box", "length": 0.1, "radius": 0.05, "density": 1240.0},
            },
            "instances": [
                {"name": "a", "part": "link"},
                {"name": "b", "part": "link"},
                {"name": "c", "part": "plate"},
            ],
            "structures": [[["a", "b"], ["b", "c"]]],
        }
    )
    representation = identity_representation(space)
    design = decode(space, representation, [0.25, 0.75, 1.0, 0.0, 0.5, 0.5, 0.5, 0.5])
    expected = {
        "a": 2700.0 * math.pi * (0.01 + 0.04 * 0.75) ** 2 * (0.2 + 0.4 * 0.25),
        "b": 2700.0 * math.pi * 0.01**2 * 0.6,
        "c": 1240.0 * 0.1**2 * 0.1,
    }
    root = ET.fromstring(design_to_urdf(design).split("\n", 1)[1])
    for link in design.links:
        assert link.mass == pytest.approx(expected[link.name], rel=1e-14)
        inertial = root.find(f"link[@name='{link.name}']/inertial")
        assert inertial is not None
        mass, tensor = inertial.find("mass"), inertial.find("inertia")
        assert mass is not None and tensor is not None
        assert float(mass.get("value", "nan")) == link.mass
        r, h, m = link.radius, link.length, link.mass
        if link.shape == "cylinder":
            assert float(tensor.get("ixx", "nan")) == pytest.approx(m * (3 * r * r + h * h) / 12)
            assert float(tensor.get("izz", "nan")) == pytest.approx(m * r * r / 2)
        else:
            assert float(tensor.get("izz", "nan")) == pytest.approx(m * 8 * r * r / 12)
    assert design_mass(design) == pytest.approx(sum(expected.values()), rel=1e-14)
    body = load(client, design_to_urdf(design), tmp_path / "dense.urdf")
    check_matches(client, body, design)  # PyBullet's mass and inertia are the derived ones
