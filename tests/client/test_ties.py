"""Tied instances (``same_as``, ``mirror``): searched once, decoded to equal specs, a
mirrored joint's axis reflected, bad ties refused with the instance named."""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from pydantic import ValidationError

from adclient.decode import (
    axis_from_angles,
    decode,
    design_params,
    identity_representation,
    onehot_representation,
    spec_layout,
)
from adclient.design import DesignSpace
from adclient.encode import encode

ROOT = Path(__file__).resolve().parents[2]
QUADRUPED = yaml.safe_load((ROOT / "examples" / "quadruped.yaml").read_text(encoding="utf-8"))


def _space(instances: list[dict[str, Any]], edges: list[list[str]]) -> dict[str, Any]:
    return {
        "type": "design",
        "parts": {
            "body": {"length": 0.4, "radius": 0.05, "mass": 2.0},
            "leg": {"length": {"low": 0.1, "high": 0.3}, "radius": 0.03, "mass": 0.3},
        },
        "instances": instances,
        "structures": [edges],
    }


PAIR = _space(
    [
        {"name": "torso", "part": "body"},
        {"name": "left", "part": "leg"},
        {"name": "right", "same_as": "left", "mirror": "y"},
    ],
    [["torso", "left"], ["torso", "right"]],
)


def test_the_quadruped_searches_its_front_left_leg_only() -> None:
    tied = DesignSpace.model_validate(QUADRUPED["space"])
    assert len(tied.free_specs()) == 6
    assert {key.split(".")[0] for key, _ in tied.free_specs()} == {
        "front_left",
        "front_left_shin",
    }


def _decoded(space_json: dict[str, Any], seed: int):
    space = DesignSpace.model_validate(space_json)
    representation = identity_representation(space)
    x = np.random.default_rng(seed).random(len(representation.bounds[0]))
    return space, representation, decode(space, representation, x.tolist())


@pytest.mark.parametrize("seed", range(20))
def test_tied_instances_get_their_sources_specs_and_mirrored_axes(seed: int) -> None:
    _, _, design = _decoded(QUADRUPED["space"], seed)
    links = {link.name: link for link in design.links}
    joints = {joint.child: joint for joint in design.joints}
    for side in ("front_right", "back_left", "back_right"):
        for part in ("", "_shin"):
            assert links[side + part].length == links["front_left" + part].length
            assert links[side + part].mass == links["front_left" + part].mass
    ax, ay, az = joints["front_left"].axis
    reflected = {
        "front_left": (ax, ay, az),
        "front_right": (-ax, ay, -az),  # across y = 0: -(ax, -ay, az)
        "back_left": (ax, ay, az),
        "back_right": (-ax, ay, -az),  # front_right copied
    }
    for name, expected in reflected.items():
        assert joints[name].axis == pytest.approx(expected, abs=1e-12)
        assert joints[name].lower == joints["front_left"].lower
        assert joints[name].upper == joints["front_left"].upper
    assert joints["back_left"].position == 0.0
    assert joints["front_left"].position == 1.0


@pytest.mark.parametrize(
    ("planes", "sign"),
    [
        (["x"], (1, -1, -1)),
        (["y"], (-1, 1, -1)),
        (["x", "y"], (-1, -1, 1)),
        (["y", "y"], (1, 1, 1)),
    ],
)
def test_mirrors_compose_along_a_chain(planes: list[str], sign: tuple[int, int, int]) -> None:
    instances: list[dict[str, Any]] = [
        {"name": "torso", "part": "body"},
        {"name": "l0", "part": "leg"},
    ]
    for k, plane in enumerate(planes, start=1):
        instances.append({"name": f"l{k}", "same_as": f"l{k - 1}", "mirror": plane})
    edges = [["torso", instance["name"]] for instance in instances[1:]]
    _, _, design = _decoded(_space(instances, edges), 3)
    joints = {joint.child: joint for joint in design.joints}
    source = np.array(joints["l0"].axis)
    assert np.array(joints[f"l{len(planes)}"].axis) == pytest.approx(source * sign, abs=1e-12)
    last = joints[f"l{len(planes)}"]
    assert axis_from_angles(last.axis_theta, last.axis_phi) == pytest.approx(last.axis)


def test_params_show_both_instances_and_encode_reads_them_back() -> None:
    space, representation, design = _decoded(PAIR, 7)
    params = design_params(design)
    assert params["right.length"] == params["left.length"]
    assert params["right.joint.axis_theta"] == pytest.approx(
        math.pi - params["left.joint.axis_theta"]
    )
    vector = encode(space, representation, params)
    assert decode(space, representation, vector) == design
    left_only = {k: v for k, v in params.items() if not k.startswith("right.")}
    assert encode(space, representation, left_only) == vector


@pytest.mark.parametrize(
    ("key", "change"),
    [("right.length", 0.01), ("right.joint.axis_theta", 0.1), ("right.radius", 0.001)],
)
def test_a_tied_spec_that_differs_from_its_source_is_refused(key: str, change: float) -> None:
    space, representation, design = _decoded(PAIR, 7)
    params = design_params(design)
    params[key] += change
    with pytest.raises(ValueError, match=rf"{key}.*tied to 'left'"):
        encode(space, representation, params)


def test_a_tied_instance_may_sit_elsewhere_on_its_parent() -> None:
    space = DesignSpace.model_validate(
        _space(
            [
                {"name": "torso", "part": "body"},
                {"name": "front", "part": "leg"},
                {
                    "name": "back",
                    "same_as": "front",
                    "joint_overrides": {"position": {"low": 0.0, "high": 0.5}},
                },
            ],
            [["torso", "front"], ["torso", "back"]],
        )
    )
    names = spec_layout(space).names
    assert "back.joint.position" in names
    assert not [name for name in names if name.startswith("back.") and "position" not in name]


def _refusal(space: dict[str, Any]) -> str:
    with pytest.raises(ValidationError) as caught:
        DesignSpace.model_validate(space)
    return str(caught.value)


@pytest.mark.parametrize(
    ("instances", "message"),
    [
        (
            [
                {"name": "torso", "part": "body"},
                {"name": "a", "same_as": "b"},
                {"name": "b", "same_as": "a"},
            ],
            r"cycle \(a -> b -> a\)",
        ),
        (
            [
                {"name": "torso", "part": "body"},
                {"name": "a", "part": "leg", "same_as": "a"},
                {"name": "b", "part": "leg"},
            ],
            r"cycle \(a -> a\)",
        ),
        (
            [
                {"name": "torso", "part": "body"},
                {"name": "a", "part": "leg"},
                {"name": "b", "same_as": "nope"},
            ],
            r"'b': same_as names unknown instance 'nope'",
        ),
        (
            [
                {"name": "torso", "part": "body"},
                {"name": "a", "part": "leg"},
                {"name": "b", "part": "leg", "mirror": "y"},
            ],
            r"'b': mirror: y needs same_as",
        ),
        (
            [
                {"name": "torso", "part": "body"},
                {"name": "a", "part": "leg"},
                {"name": "b", "same_as": "a", "overrides": {"length": 0.2}},
            ],
            r"'b': same_as 'a' .* overrides none of them \(length\)",
        ),
        (
            [
                {"name": "torso", "part": "body"},
                {"name": "a", "part": "leg"},
                {"name": "b", "same_as": "a", "joint_overrides": {"effort": 3.0}},
            ],
            r"overrides none of them \(effort\)",
        ),
        (
            [
                {"name": "torso", "part": "body"},
                {"name": "a", "part": "leg"},
                {"name": "b", "part": "body", "same_as": "a"},
            ],
            r"'b'\): part 'body' differs from 'a''s part 'leg'",
        ),
        (
            [{"name": "torso", "part": "body"}, {"name": "a", "part": "leg"}, {"name": "b"}],
            r"'b': part is required",
        ),
        (
            [
                {"name": "torso", "part": "body"},
                {"name": "a", "part": "leg"},
                {"name": "b", "same_as": "a", "mirror": "z"},
            ],
            r"mirror",
        ),
    ],
)
def test_bad_ties_are_refused_with_the_instance_named(
    instances: list[dict[str, Any]], message: str
) -> None:
    refusal = _refusal(_space(instances, [["torso", "a"], ["torso", "b"]]))
    assert re.search(message, refusal), refusal


def test_an_untied_space_serialises_as_before() -> None:
    instances = [{"name": "torso", "part": "body"}, *({"name": n, "part": "leg"} for n in "lr")]
    free = DesignSpace.model_validate(_space(instances, [["torso", "l"], ["torso", "r"]]))
    for instance in free.model_dump(mode="json")["instances"]:
        assert "same_as" not in instance and "mirror" not in instance
    tied = DesignSpace.model_validate(PAIR).model_dump(mode="json")
    assert tied["instances"][2] == {
        "name": "right",
        "part": "leg",
        "same_as": "left",
        "mirror": "y",
        "overrides": {},
        "joint_overrides": {},
    }
    assert DesignSpace.model_validate(tied).ties() == DesignSpace.model_validate(PAIR).ties()


MOTORS = {
    "small": {"effort": 2.0, "velocity": 6.0, "cost": 10.0},
    "large": {"effort": 9.0, "velocity": 3.0, "cost": 40.0},
    "mid": {"effort": 5.0, "velocity": 4.0, "cost": 20.0},
}


def _chain(
    tied: list[dict[str, Any]], structures: list[list[list[str]]], **joint: Any
) -> dict[str, Any]:
    """Links a, b, c (and d) whose joints choose motors; ``tied`` replaces instances."""
    instances = {name: {"name": name, "part": "leg"} for name in "abcd"}
    instances.update({instance["name"]: instance for instance in tied})
    used = {name for edges in structures for edge in edges for name in edge}
    return {
        **_space([instances[name] for name in "abcd" if name in used], []),
        "joint": {"choose": "motors", "offset_yaw": {"low": -0.5, "high": 0.5}, **joint},
        "catalogues": {"motors": MOTORS},
        "structures": structures,
    }


CHAIN = [[["a", "b"], ["b", "c"]]]
ROOT_TIES = {
    "last link as the root": _chain([{"name": "c", "same_as": "a"}], CHAIN),
    "a child as the root": _chain([{"name": "b", "same_as": "a"}], CHAIN),
    "a child mirroring the root": _chain([{"name": "b", "same_as": "a", "mirror": "y"}], CHAIN),
    "a chain to the root": _chain(
        [{"name": "b", "same_as": "a", "mirror": "x"}, {"name": "c", "same_as": "b"}], CHAIN
    ),
    "mirrors that differ": _chain(
        [
            {"name": "c", "same_as": "a", "mirror": "y"},
            {"name": "d", "same_as": "c", "mirror": "x"},
        ],
        [[["a", "b"], ["b", "c"], ["b", "d"]]],
    ),
    "a stand-in sitting where it likes": _chain(
        [
            {
                "name": "b",
                "same_as": "a",
                "joint_overrides": {"position": {"low": 0.2, "high": 0.8}},
            },
            {"name": "c", "same_as": "a", "mirror": "y"},
        ],
        CHAIN,
        position={"low": 0.5, "high": 1.0},
    ),
    "a source absent from a structure": _chain(
        [{"name": "c", "same_as": "a", "mirror": "y"}],
        [[["b", "a"], ["b", "c"]], [["b", "c"]]],
    ),
}


@pytest.mark.parametrize("space_json", ROOT_TIES.values(), ids=ROOT_TIES.keys())
def test_a_tie_to_an_instance_without_a_joint_takes_the_joint_specs_searched_for_it(
    space_json: dict[str, Any],
) -> None:
    """Issue 36: a tie whose source is the root (or absent) was created, and every ask
    failed (``encode: spec 'a.joint.choice.0' is missing``): the source's joint slots,
    searched for its tied instances, have no joint of the source's to be read from.
    They are read from a tied instance's, and every design goes there and back to the
    bit, from the design and from its params (the tied instance's alone giving them)."""
    space = DesignSpace.model_validate(space_json)
    representation = (
        identity_representation(space)
        if len(space.tree_structures()) == 1
        else onehot_representation(space)
    )
    assert "a.joint.choice.0" in spec_layout(space).names
    rng = np.random.default_rng(5)
    for _ in range(50):
        vector = rng.uniform(*representation.bounds).tolist()
        design = decode(space, representation, vector)
        params = design_params(design)
        assert decode(space, representation, encode(space, representation, design)) == design
        again = decode(space, representation, encode(space, representation, params))
        assert design_params(again) == params


def test_a_tie_to_the_root_names_the_tied_joint_when_it_is_missing_or_off() -> None:
    space = DesignSpace.model_validate(ROOT_TIES["a child mirroring the root"])
    representation = identity_representation(space)
    params = design_params(decode(space, representation, [0.5] * len(representation.bounds[0])))
    for key in ("b.joint.choice", "b.joint.offset_yaw"):
        with pytest.raises(ValueError, match=rf"given as '{key}' \('b' is tied to 'a', which"):
            encode(space, representation, {k: v for k, v in params.items() if k != key})
    with pytest.raises(ValueError, match=r"given as 'b.joint.offset_yaw' .* lies outside"):
        encode(space, representation, {**params, "b.joint.offset_yaw": 2.0})
    other = "large" if params["b.joint.choice"] != "large" else "mid"
    chosen = {k: v for k, v in params.items() if k not in ("b.joint.effort", "b.joint.velocity")}
    vector = encode(space, representation, {**chosen, "b.joint.choice": other})
    joints = {joint.child: joint for joint in decode(space, representation, vector).joints}
    assert (joints["b"].choice, joints["b"].effort) == (other, MOTORS[other]["effort"])


def test_a_source_s_joint_spec_that_no_tied_instance_takes_is_not_searched() -> None:
    """Issue 36: the root ``left``'s joint position was searched (and asked for on
    enqueue, naming a spec no params show) though ``right``, the only instance that
    takes ``left``'s joint, sits where its own position says."""
    space = DesignSpace.model_validate(
        {
            **_space(
                [
                    {"name": "left", "part": "leg"},
                    {"name": "torso", "part": "body"},
                    {"name": "right", "same_as": "left", "joint_overrides": {"position": 0.3}},
                ],
                [["left", "torso"], ["torso", "right"]],
            ),
            "joint": {"position": {"low": 0.5, "high": 1.0}},
        }
    )
    names = spec_layout(space).names
    assert "left.joint.axis_theta" in names and "torso.joint.position" in names
    assert "left.joint.position" not in names
    representation = identity_representation(space)
    design = decode(space, representation, [0.25] * len(names))
    assert {joint.child: joint.position for joint in design.joints}["right"] == 0.3
    params = design_params(design)
    assert decode(space, representation, encode(space, representation, params)) == design
