"""Design-space validation: good spaces load, bad ones fail with a message naming the problem."""

from __future__ import annotations

import copy
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from adclient.decode import decode, identity_representation, spec_layout
from adclient.design import DesignSpace
from adclient.encode import encode
from adclient.schemas import StudyCreate
from adclient.similarity import structure_similarity, tree_edit_distance
from tests.client.design_strategies import NAMES, single_structure_spaces, trees

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"

BASE: dict[str, Any] = {
    "type": "design",
    "parts": {"link": {"length": {"low": 0.2, "high": 0.6}, "radius": 0.04, "mass": 1.0}},
    "instances": [
        {"name": "a", "part": "link"},
        {"name": "b", "part": "link"},
        {"name": "c", "part": "link"},
    ],
    "structures": [[["a", "b"], ["b", "c"]]],
}


def space_with(**changes: Any) -> dict[str, Any]:
    body = copy.deepcopy(BASE)
    body.update(changes)
    return body


def error_of(body: dict[str, Any]) -> str:
    with pytest.raises(ValidationError) as caught:
        DesignSpace.model_validate(body)
    return str(caught.value)


@pytest.mark.parametrize("name", ["stand-up", "diagonal-gesture", "multi-structure"])
def test_examples_are_valid_study_bodies(name: str) -> None:
    body = StudyCreate.model_validate(yaml.safe_load((EXAMPLES / f"{name}.yaml").read_text()))
    space = body.space
    assert isinstance(space, DesignSpace)
    assert [instance.name for instance in space.instances][:3] == ["a", "b", "c"]
    assert body.task is not None and body.max_trials == 15
    names, _ = space.spec_slots()
    assert "b.joint.axis_theta" in names and "c.joint.axis_phi" in names
    assert "a.joint.axis_theta" not in names  # the root has no joint


def test_bound_low_not_below_high() -> None:
    body = space_with(parts={"link": {"length": {"low": 0.6, "high": 0.2}}})
    message = error_of(body)
    assert "parts.link.length" in message and "low (0.6) must be < high (0.2)" in message
    assert "low (0.3) must be < high (0.3)" in error_of(
        space_with(parts={"link": {"length": {"low": 0.3, "high": 0.3}}})
    )


@pytest.mark.parametrize("bad", [math.inf, -math.inf, math.nan])
def test_non_finite_specs(bad: float) -> None:
    assert "finite" in error_of(space_with(parts={"link": {"length": {"low": 0.1, "high": bad}}}))
    assert "finite" in error_of(space_with(parts={"link": {"mass": bad}}))


def test_spec_must_be_number_or_bound() -> None:
    assert "a spec is a number" in error_of(space_with(parts={"link": {"mass": "heavy"}}))
    assert "radius: must be > 0" in error_of(space_with(parts={"link": {"radius": 0.0}}))
    message = error_of(space_with(joint={"position": {"low": 0.5, "high": 1.5}}))
    assert "position: must lie in [0, 1]" in message


def test_joint_limits_must_not_cross() -> None:
    message = error_of(space_with(joint={"lower": {"low": -1.0, "high": 0.5}, "upper": 0.2}))
    assert "lower" in message and "can exceed upper" in message
    body = space_with()
    body["instances"][1]["joint_overrides"] = {"lower": 2.0}
    assert "instances[1] ('b')" in error_of(body)


def test_unknown_part() -> None:
    body = space_with()
    body["instances"][2]["part"] = "wheel"
    message = error_of(body)
    assert "instances[2] ('c'): unknown part 'wheel'" in message and "known: link" in message


def test_unknown_override_keys() -> None:
    body = space_with()
    body["instances"][0]["overrides"] = {"lenght": 0.3}
    assert "overrides has unknown key 'lenght'" in error_of(body)
    body = space_with()
    body["instances"][1]["joint_overrides"] = {"axis": 0.3}
    assert "joint_overrides has unknown key 'axis'" in error_of(body)


def test_duplicate_instance_names() -> None:
    body = space_with()
    body["instances"][2]["name"] = "a"
    assert "instances[2]: duplicate instance name 'a' (also instances[0])" in error_of(body)


def test_bad_instance_name_pattern() -> None:
    body = space_with()
    body["instances"][0]["name"] = 'a"><x'
    assert "instances.0.name" in error_of(body)


@pytest.mark.parametrize(
    ("structure", "expected"),
    [
        ([["a", "b"], ["b", "a"], ["b", "c"]], "no root (a cycle)"),
        ([["a", "b"], ["c", "b"]], "'b' has two parents"),
        ([["a", "b"], ["b", "c"], ["c", "a"]], "no root (a cycle)"),
        ([["a", "b"], ["b", "c"], ["c", "b"]], "'b' has two parents"),
        ([["a", "a"]], "joins 'a' to itself"),
        ([], "at least one edge"),
        ([["a", "b"], ["b", "z"]], "structures[0][1]: unknown instance 'z'"),
    ],
)
def test_structure_not_a_tree(structure: list[list[str]], expected: str) -> None:
    assert expected in error_of(space_with(structures=[structure]))


def test_cycle_without_root_and_disconnected() -> None:
    body = space_with(
        instances=[{"name": n, "part": "link"} for n in "abcd"],
        structures=[[["a", "b"], ["c", "d"]]],
    )
    assert "several roots ('a', 'c')" in error_of(body)
    body = space_with(structures=[[["a", "b"], ["b", "c"]], [["b", "c"], ["c", "b"]]])
    message = error_of(body)
    assert "structures[1]: not a tree: it has no root (a cycle)" in message


def test_unused_instances_and_duplicate_structures() -> None:
    body = space_with(structures=[[["a", "b"]]])
    assert "'c' appear in no structure" in error_of(body)
    body = space_with(structures=[[["a", "b"], ["b", "c"]], [["b", "c"], ["a", "b"]]])
    assert "structures[1]: same tree as structures[0]" in error_of(body)


def test_too_many_structures() -> None:
    body = space_with(
        structures=[[["a", "b"], ["b", "c"]], [["a", "b"], ["a", "c"]], [["a", "c"], ["c", "b"]]],
        max_structures=2,
    )
    assert "3 structures, more than max_structures=2" in error_of(body)
    body = space_with(instances=[{"name": n, "part": "link"} for n in "abcde"], structures="all")
    assert "'all' over 5 instances gives 125 trees, more than max_structures=64" in error_of(body)
    assert "at least two instances" in error_of(
        space_with(instances=[{"name": "a", "part": "link"}], structures="all")
    )


def test_no_free_spec_is_one_design() -> None:
    """Issue 39: a space with every spec given and one structure is one design (it was
    refused as nothing to search); several structures are searched even then."""
    body = space_with(parts={"link": {"length": 0.4}}, joint={"axis_theta": 0.0, "axis_phi": 0.0})
    space = DesignSpace.model_validate(body)
    assert space.searches_nothing and space.spec_slots() == ([], [])
    body["structures"] = [[["a", "b"], ["b", "c"]], [["a", "b"], ["a", "c"]]]
    space = DesignSpace.model_validate(body)
    assert len(space.tree_structures()) == 2 and not space.searches_nothing


def test_a_searched_spec_may_be_log_scaled() -> None:
    body = space_with(
        parts={
            "link": {
                "length": {"low": 0.2, "high": 0.6},
                "mass": {"low": 0.1, "high": 10, "log": True},
            }
        },
        joint={"effort": {"low": 1, "high": 100, "log": True}},
    )
    space = DesignSpace.model_validate(body)
    logs = {key: bound.log for key, bound in space.free_specs()}
    assert logs["a.mass"] and logs["c.joint.effort"] and not logs["a.length"]
    assert not logs["b.joint.axis_theta"]
    names, ranges = space.spec_slots()  # physical ranges, whatever the scale
    assert ranges[names.index("a.mass")] == (0.1, 10.0)
    dumped = space.model_dump(mode="json")
    assert dumped["parts"]["link"]["mass"] == {"low": 0.1, "high": 10.0, "log": True}
    # a linear spec's JSON is what it was before log specs: no log key
    assert dumped["parts"]["link"]["length"] == {"low": 0.2, "high": 0.6}
    assert dumped["joint"]["axis_theta"] == {"low": 0.0, "high": math.pi}
    assert DesignSpace.model_validate(dumped).free_specs() == space.free_specs()


@pytest.mark.parametrize("low", [0.0, -0.5])
def test_a_log_spec_needs_low_above_zero(low: float) -> None:
    message = error_of(space_with(joint={"lower": {"low": low - 1, "high": low, "log": True}}))
    assert "joint.lower" in message
    assert f"log: a log scale needs low > 0, got {low - 1}" in message
    message = error_of(space_with(joint={"axis_theta": {"low": low, "high": 1.0, "log": True}}))
    assert "joint.axis_theta" in message
    assert f"log: a log scale needs low > 0, got {low}" in message
    # the same spec without log is fine, and log: false is the default
    space_with(joint={"axis_theta": {"low": low, "high": 1.0, "log": False}})
    DesignSpace.model_validate(space_with(joint={"axis_theta": {"low": low, "high": 1.0}}))


def test_a_log_spec_needs_a_normal_low() -> None:
    """A subnormal low (5e-324) keeps too few bits for a slot to survive decode and
    encode (a slot of 0.015625 came back 5.2e-9 off); the smallest normal float works."""
    message = error_of(space_with(joint={"axis_theta": {"low": 5e-324, "high": 1.0, "log": True}}))
    assert "joint.axis_theta" in message
    assert f"log: a log scale's low must be at least {sys.float_info.min}" in message
    assert "got 5e-324" in message
    body = space_with(joint={"axis_theta": {"low": sys.float_info.min, "high": 1.0, "log": True}})
    space = DesignSpace.model_validate(body)
    representation = identity_representation(space)
    layout = spec_layout(space)
    slot = layout.names.index("b.joint.axis_theta")
    for x in (0.0, 0.015625, 0.3, 0.999, 1.0):
        vector = [0.5] * layout.size
        vector[slot] = x
        design = decode(space, representation, vector)
        assert encode(space, representation, design)[slot] == pytest.approx(x, abs=1e-12)


def test_a_log_spec_is_checked_like_any_other() -> None:
    assert "log: Input should be a valid boolean" in error_of(
        space_with(parts={"link": {"length": {"low": 0.2, "high": 0.6, "log": "often"}}})
    )
    assert "Extra inputs are not permitted" in error_of(
        space_with(parts={"link": {"length": {"low": 0.2, "high": 0.6, "base": 10}}})
    )
    message = error_of(
        space_with(joint={"lower": {"low": 0.5, "high": 2.0, "log": True}, "upper": 1.0})
    )
    assert "lower ({low: 0.5, high: 2.0, log: true}) can exceed upper (1.0)" in message


def test_unknown_fields_rejected() -> None:
    assert "Extra inputs are not permitted" in error_of(space_with(colour="red"))


def test_errors_reach_the_study_body() -> None:
    body = {"name": "s", "space": space_with(parts={"link": {"length": {"low": 1, "high": 0}}})}
    with pytest.raises(ValidationError) as caught:
        StudyCreate.model_validate(body)
    assert "must be < high" in str(caught.value)


@settings(max_examples=30, deadline=None)
@given(single_structure_spaces())
def test_generated_spaces_are_valid_and_round_trip(body: dict[str, Any]) -> None:
    space = DesignSpace.model_validate(body)
    again = DesignSpace.model_validate(space.model_dump(mode="json"))
    assert again.tree_structures() == space.tree_structures()
    assert again.spec_slots() == space.spec_slots()
    assert again.free_specs() == space.free_specs()  # log scales included
    names, ranges = space.spec_slots()
    assert names and all(low < high for low, high in ranges)


@settings(max_examples=30, deadline=None)
@given(st.integers(3, 5).flatmap(lambda n: st.tuples(st.just(n), trees(NAMES[:n]))), st.data())
def test_adding_an_edge_to_a_tree_breaks_it(case: tuple[int, list], data: st.DataObject) -> None:
    n, tree = case
    names = NAMES[:n]
    extra = data.draw(
        st.tuples(st.sampled_from(names), st.sampled_from(names)).filter(
            lambda e: e not in tree and (e[1], e[0]) not in tree and e[0] != e[1]
        )
    )
    body = space_with(
        instances=[{"name": name, "part": "link"} for name in names],
        structures=[[list(edge) for edge in tree]],
    )
    DesignSpace.model_validate(body)
    body["structures"] = [[list(edge) for edge in [*tree, extra]]]
    assert "not a tree" in error_of(body)


@pytest.mark.parametrize("n", [2, 3, 4, 5])
def test_all_trees_enumerated(n: int) -> None:
    names = NAMES[:n]
    space = DesignSpace.model_validate(
        space_with(instances=[{"name": name, "part": "link"} for name in names], structures="all")
        | {"max_structures": 1000}
    )
    structures = space.tree_structures()
    assert len(structures) == n ** (n - 2)  # Cayley
    assert len({frozenset(s) for s in structures}) == len(structures)
    for structure in structures:
        assert len(structure) == n - 1
        children = [child for _, child in structure]
        assert sorted(children) == sorted(names[1:])  # rooted at the first instance
    # explicit listing of the same trees validates too
    DesignSpace.model_validate(
        space_with(
            instances=[{"name": name, "part": "link"} for name in names],
            structures=[[list(e) for e in s] for s in structures],
            max_structures=1000,
        )
    )


# -- structure similarity -------------------------------------------------------------


def test_similarity_known_values() -> None:
    chain = [("a", "b"), ("b", "c")]
    assert structure_similarity(chain, list(reversed(chain))) == 1.0
    assert tree_edit_distance(chain, [("a", "b"), ("a", "c")]) == 2.0  # move c up
    assert tree_edit_distance(chain, [("a", "c"), ("c", "b")]) == 2.0  # swap b and c
    same_type = {"a": "link", "b": "link", "c": "link"}
    assert tree_edit_distance(chain, [("a", "c"), ("c", "b")], same_type) == 1.0
    assert tree_edit_distance(chain, [("a", "b")]) == 1.0  # drop c
    assert structure_similarity(chain, [("a", "b")]) == pytest.approx(1 - 2 / 6)


@settings(max_examples=40, deadline=None)
@given(st.data())
def test_similarity_is_a_bounded_symmetric_metric(data: st.DataObject) -> None:
    def tree() -> list[tuple[str, str]]:
        size = data.draw(st.integers(2, 6))
        return data.draw(trees(NAMES[:size]))

    a, b, c = tree(), tree(), tree()
    part_of = data.draw(st.none() | st.just({n: ("x" if n in "abc" else "y") for n in NAMES}))
    ab = tree_edit_distance(a, b, part_of)
    assert ab == tree_edit_distance(b, a, part_of)
    assert tree_edit_distance(a, a, part_of) == 0.0
    assert (ab == 0.0) == (frozenset(a) == frozenset(b))
    assert ab <= tree_edit_distance(a, c, part_of) + tree_edit_distance(c, b, part_of) + 1e-12
    similarity = structure_similarity(a, b, part_of)
    assert 0.0 <= similarity <= 1.0
    assert (similarity == 1.0) == (frozenset(a) == frozenset(b))


# ------------------------------------------------------------ mass from density

DENSE: dict[str, Any] = {
    "length": {"low": 0.2, "high": 0.6},
    "radius": {"low": 0.01, "high": 0.05, "log": True},
    "density": 2700.0,
}


def test_a_part_may_give_density_instead_of_mass() -> None:
    space = DesignSpace.model_validate(space_with(parts={"link": DENSE}))
    part = space.parts["link"]
    assert part.mass is None and part.density == 2700.0
    assert [space.mass_spec(name) for name in "abc"] == ["density"] * 3
    assert space.part_spec("a", "density") == 2700.0 and space.part_spec("a", "mass") is None
    names, _ = space.spec_slots()
    assert names[:2] == ["a.length", "a.radius"] and not any("mass" in n for n in names)
    # a searched density is a slot of its own, after the part's other specs
    searched = {**DENSE, "density": {"low": 500.0, "high": 8000.0, "log": True}}
    space = DesignSpace.model_validate(space_with(parts={"link": searched}))
    names, ranges = space.spec_slots()
    assert names[:3] == ["a.length", "a.radius", "a.density"]
    assert ranges[2] == (500.0, 8000.0) and dict(space.free_specs())["a.density"].log


def test_a_stored_space_writes_only_the_mass_spec_it_gives() -> None:
    dense = DesignSpace.model_validate(space_with(parts={"link": DENSE}))
    dumped = dense.model_dump(mode="json")["parts"]["link"]
    assert "mass" not in dumped and dumped["density"] == 2700.0
    again = DesignSpace.model_validate(dense.model_dump(mode="json"))
    assert again.free_specs() == dense.free_specs() and again.parts == dense.parts
    # a space with mass has the JSON it had before density existed
    plain = DesignSpace.model_validate(space_with())
    assert plain.model_dump(mode="json")["parts"]["link"] == {
        "shape": "cylinder",
        "length": {"low": 0.2, "high": 0.6},
        "radius": 0.04,
        "mass": 1.0,
    }
    # a part that gives neither keeps the default mass
    default = DesignSpace.model_validate(space_with(parts={"link": {"length": DENSE["length"]}}))
    assert default.parts["link"].mass == 1.0 and default.mass_spec("a") == "mass"


def test_mass_and_density_together_are_refused_naming_the_part() -> None:
    body = space_with(parts={"link": {**DENSE, "mass": 1.0}})
    message = error_of(body)
    assert "parts: part 'link' gives both mass (1.0) and density (2700.0)" in message
    assert "leave one out" in message
    searched = {**DENSE, "mass": {"low": 0.1, "high": 2.0}}
    assert "gives both mass ({low: 0.1, high: 2.0}) and density" in error_of(
        space_with(parts={"link": searched})
    )
    assert "parts: part 'link' gives neither mass nor density" in error_of(
        space_with(parts={"link": {"length": DENSE["length"], "mass": None}})
    )
    # through a study body, as the server words it
    with pytest.raises(ValidationError) as caught:
        StudyCreate.model_validate({"name": "s", "space": body})
    assert "part 'link' gives both mass" in str(caught.value)


@pytest.mark.parametrize("bad", [0.0, -1.0, {"low": 0.0, "high": 10.0}, math.nan, "dense"])
def test_a_density_is_checked_like_any_spec(bad: Any) -> None:
    message = error_of(space_with(parts={"link": {**DENSE, "density": bad}}))
    assert "density" in message
    assert any(text in message for text in ("must be > 0", "finite", "a spec is a number")), message


def test_an_instance_override_replaces_its_parts_mass_spec() -> None:
    body = space_with(parts={"link": DENSE})
    body["instances"][1]["overrides"] = {"mass": {"low": 0.1, "high": 1.0}}  # a payload
    body["instances"][2]["overrides"] = {"density": 1240.0}
    space = DesignSpace.model_validate(body)
    assert [space.mass_spec(name) for name in "abc"] == ["density", "mass", "density"]
    assert space.part_spec("b", "density") is None and space.part_spec("c", "density") == 1240.0
    names, _ = space.spec_slots()
    assert "b.mass" in names and "a.mass" not in names
    # and the other way round: a mass part, one instance of density
    body = space_with()
    body["instances"][0]["overrides"] = {"density": {"low": 1000.0, "high": 3000.0}}
    space = DesignSpace.model_validate(body)
    assert space.mass_spec("a") == "density" and space.part_spec("a", "mass") is None
    # both at once is refused, naming the instance
    body["instances"][2]["overrides"] = {"mass": 0.5, "density": 900.0}
    message = error_of(body)
    assert "instances[2] ('c'): overrides gives both mass (0.5) and density (900.0)" in message
    assert "override only one" in message


def test_a_space_equals_its_copy_after_its_trees_are_listed() -> None:
    """The cached trees (and the tied-instance table) are not part of what a space is."""
    body = space_with(structures="all")
    used = DesignSpace.model_validate(body)
    assert len(used.tree_structures()) == 3 and used.uses_offsets() is False
    fresh = DesignSpace.model_validate(body)
    assert used == fresh and fresh == used
    assert used != DesignSpace.model_validate(space_with(structures=[[["a", "b"], ["b", "c"]]]))


@pytest.mark.parametrize(
    ("changes", "named"),
    [
        ({"parts": {"link": {"length": {"low": "0.2", "high": 0.6}, "radius": 0.04}}}, "low"),
        ({"parts": {"link": {"length": {"low": 0.2, "high": 0.6}, "radius": True}}}, "radius"),
        ({"max_structures": "64"}, "max_structures"),
        ({"max_structures": 64.5}, "max_structures"),
        ({"structures": [[["a", "b"], ["b", 3]]]}, "structures"),
    ],
)
def test_numbers_are_taken_only_as_json_gives_them(changes: dict[str, Any], named: str) -> None:
    """A quoted number, a truth value for a number or a fractional number for an
    integer is refused by name (the lax models read "0.2" as 0.2 and true as 1.0); an
    integral number is an integer, from NumPy too; an edge is an array of two names, as
    JSON and YAML give it."""
    assert named in error_of(space_with(**changes))
    for integral in (64, 64.0, np.int64(64), np.float32(64.0)):
        space = DesignSpace.model_validate(space_with(max_structures=integral))
        assert space.max_structures == 64 and type(space.max_structures) is int
