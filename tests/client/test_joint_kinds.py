"""Joint kinds and capsules in design spaces (issue 28): a joint is revolute,
continuous, prismatic or fixed (shared, or per instance with ``joint_type``); the specs
a kind has no use for are never searched and decode to placeholders; a capsule link's
volume counts its balls; the URDF says each kind and shape as PyBullet reads it."""

from __future__ import annotations

import math
import xml.etree.ElementTree as ElementTree
from typing import Any

import pytest
from pydantic import ValidationError

from adclient.decode import decode, design_params, identity_representation, spec_layout
from adclient.design import DesignSpace
from adclient.encode import encode
from adclient.specs import link_volume
from adclient.urdf import design_to_urdf

LEG = {"shape": "capsule", "length": {"low": 0.1, "high": 0.3}, "radius": 0.03, "density": 1000.0}


def space(**instances: dict[str, Any]) -> DesignSpace:
    body = {
        "type": "design",
        "parts": {"body": {"shape": "box", "length": 0.3, "radius": 0.1, "mass": 2.0}, "leg": LEG},
        "catalogues": {"motors": {"small": {"effort": 1.0}, "big": {"effort": 8.0}}},
        "joint": {"choose": "motors"},
        "instances": [{"name": "a", "part": "body"}]
        + [{"name": name, "part": "leg", **extra} for name, extra in instances.items()],
        "structures": [[["a", name] for name in instances]],
    }
    return DesignSpace.model_validate(body)


def test_each_kind_searches_only_the_specs_it_uses() -> None:
    kinds = space(
        b={},
        c={"joint_type": "continuous"},
        d={"joint_type": "prismatic", "joint_overrides": {"lower": 0.0, "upper": 0.2}},
        e={"joint_type": "fixed"},
    )
    names = spec_layout(kinds).names
    joint_slots = {name.split(".")[0]: [] for name in names}
    for name in names:
        joint_slots[name.split(".")[0]].append(name.split(".", 1)[1])
    assert joint_slots["b"] == [
        "length",
        "joint.choice.0",
        "joint.axis_theta",
        "joint.axis_phi",
    ]
    assert joint_slots["c"] == joint_slots["b"]  # its limits: not searched
    assert joint_slots["d"] == joint_slots["b"]
    assert joint_slots["e"] == ["length"]  # no axis, no motor: only where it sits
    representation = identity_representation(kinds)
    vector = [0.3] * len(names)
    design = decode(kinds, representation, vector)
    joints = {joint.child: joint for joint in design.joints}
    assert [joints[c].kind for c in "bcde"] == ["revolute", "continuous", "prismatic", "fixed"]
    assert (joints["c"].lower, joints["c"].upper) == (-math.pi, math.pi)
    assert (joints["d"].lower, joints["d"].upper) == (0.0, 0.2)
    assert joints["e"].axis == (0.0, 0.0, 1.0) and joints["e"].choice is None
    assert joints["b"].choice in ("small", "big")
    # the params (placeholders included) encode to a vector of the same design
    params = design_params(design)
    assert [params.get(f"{c}.joint.kind") for c in "bcde"] == [
        None,
        "continuous",
        "prismatic",
        "fixed",
    ]
    assert params["e.joint.axis_theta"] == 0.0 and params["c.joint.lower"] == -math.pi
    assert (
        design_params(decode(kinds, representation, encode(kinds, representation, params)))
        == params
    )
    # a revolute-only design's JSON has no kind in it (older workers read it)
    assert "kind" not in design.model_dump(mode="json")["joints"][0]
    assert design.model_dump(mode="json")["joints"][1]["kind"] == "continuous"


def test_the_urdf_says_each_kind_as_pybullet_reads_it() -> None:
    kinds = space(
        b={},
        c={"joint_type": "continuous"},
        d={"joint_type": "prismatic", "joint_overrides": {"lower": 0.0, "upper": 0.2}},
        e={"joint_type": "fixed"},
    )
    design = decode(kinds, identity_representation(kinds), [0.5] * spec_layout(kinds).size)
    robot = ElementTree.fromstring(design_to_urdf(design))
    joints = {joint.find("child").get("link"): joint for joint in robot.iter("joint")}  # type: ignore[union-attr]
    assert {child: joint.get("type") for child, joint in joints.items()} == {
        "b": "revolute",
        "c": "continuous",
        "d": "prismatic",
        "e": "fixed",
    }
    limit = {child: joint.find("limit") for child, joint in joints.items()}
    assert limit["e"] is None and joints["e"].find("axis") is None
    assert limit["c"] is not None and "lower" not in limit["c"].attrib
    assert limit["d"] is not None and (limit["d"].get("lower"), limit["d"].get("upper")) == (
        "0.0",
        "0.2",
    )
    leg = next(link for link in robot.iter("link") if link.get("name") == "b")
    assert [c.tag for c in leg.find("collision/geometry")] == ["capsule"]  # type: ignore[union-attr]
    # seen: a cylinder and a ball at each end (URDF viewers draw no capsule)
    seen = [next(iter(v.find("geometry"))).tag for v in leg.iter("visual")]  # type: ignore[arg-type]
    assert seen == ["cylinder", "sphere", "sphere"]


def test_a_capsule_weighs_its_balls_too() -> None:
    assert link_volume("capsule", 0.2, 0.03) == pytest.approx(
        math.pi * 0.03**2 * 0.2 + 4 / 3 * math.pi * 0.03**3, rel=1e-12
    )
    kinds = space(b={})
    design = decode(kinds, identity_representation(kinds), [1.0] * spec_layout(kinds).size)
    leg = next(link for link in design.links if link.name == "b")
    assert leg.mass == pytest.approx(1000.0 * link_volume("capsule", 0.3, 0.03), rel=1e-12)


def test_kinds_are_checked_by_name() -> None:
    with pytest.raises(ValidationError, match="joint_type"):
        space(b={"joint_type": "floating"})
    with pytest.raises(ValidationError, match="same_as 'b' takes that instance's joint"):
        space(b={"joint_type": "fixed"}, c={"same_as": "b", "joint_type": "revolute"})
    tied = space(b={"joint_type": "prismatic"}, c={"same_as": "b"})
    assert tied.joint_kind("c") == "prismatic"  # a tied joint is its source's kind


def test_offsets_turn_joints_and_show_only_where_a_space_uses_them() -> None:
    body = {
        "type": "design",
        "parts": {"leg": {"length": {"low": 0.1, "high": 0.3}, "radius": 0.03}},
        "joint": {"axis_theta": 1.5707963267948966, "axis_phi": 0.0},
        "instances": [
            {"name": "a", "part": "leg"},
            {
                "name": "l",
                "part": "leg",
                "joint_overrides": {"offset_roll": {"low": 1.0, "high": 2.0}, "offset_yaw": 0.3},
            },
            {"name": "r", "same_as": "l", "mirror": "y"},
            {"name": "x", "same_as": "l", "mirror": "x"},
        ],
        "structures": [[["a", "l"], ["a", "r"], ["a", "x"]]],
    }
    turned = DesignSpace.model_validate(body)
    layout = spec_layout(turned)
    assert "l.joint.offset_roll" in layout.names and "r.joint.offset_roll" not in layout.names
    representation = identity_representation(turned)
    design = decode(turned, representation, [0.5] * layout.size)
    offsets = {joint.child: joint.offset for joint in design.joints}
    assert offsets == {"l": (1.5, 0.0, 0.3), "r": (-1.5, 0.0, -0.3), "x": (1.5, 0.0, -0.3)}
    params = design_params(design)
    assert params["l.joint.offset_roll"] == 1.5 and params["r.joint.offset_yaw"] == -0.3
    assert (
        design_params(decode(turned, representation, encode(turned, representation, params)))
        == params
    )
    origins = {
        joint.find("child").get("link"): joint.find("origin").get("rpy")  # type: ignore[union-attr]
        for joint in ElementTree.fromstring(design_to_urdf(design)).iter("joint")
    }
    assert origins == {"l": "1.5 0.0 0.3", "r": "-1.5 0.0 -0.3", "x": "1.5 0.0 -0.3"}
    # a space that turns no joint: no offsets in its designs, its JSON or its params
    plain = space(b={})
    design = decode(plain, identity_representation(plain), [0.5] * spec_layout(plain).size)
    assert not any("offset" in key for key in design_params(design))
    assert "offset_roll" not in design.model_dump(mode="json")["joints"][0]
    assert "offset_roll" not in plain.model_dump(mode="json")["joint"]


def test_a_kind_s_unused_specs_stay_placeholders() -> None:
    """A continuous joint whose servo catalogue gives limits still turns all round; a
    joint override of a spec its kind has no use for is refused by name."""
    body = {
        "type": "design",
        "parts": {"leg": {"length": {"low": 0.1, "high": 0.3}}},
        "catalogues": {"motors": {"a": {"effort": 1.0, "lower": -0.5, "upper": 0.5}}},
        "joint": {"choose": "motors"},
        "instances": [
            {"name": "a", "part": "leg"},
            {"name": "b", "part": "leg", "joint_type": "continuous"},
            {"name": "c", "part": "leg"},
        ],
        "structures": [[["a", "b"], ["a", "c"]]],
    }
    limited = DesignSpace.model_validate(body)
    design = decode(limited, identity_representation(limited), [0.5] * spec_layout(limited).size)
    joints = {joint.child: joint for joint in design.joints}
    assert (joints["b"].lower, joints["b"].upper) == (-math.pi, math.pi)
    assert (joints["c"].lower, joints["c"].upper) == (-0.5, 0.5)  # a revolute takes them
    assert joints["b"].effort == 1.0
    with pytest.raises(ValidationError, match=r"'b'\): its joint is fixed, which has no use for"):
        space(b={"joint_type": "fixed", "joint_overrides": {"lower": 0.0}})
