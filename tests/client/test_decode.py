"""Decode/encode: exact round trips for single-structure and mixed spaces, own structures for
fused ones."""

from __future__ import annotations

import gc
import json
import math
import re
import weakref
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from adclient.decode import decode, design_params, identity_representation, spec_layout
from adclient.design import DesignSpace
from adclient.encode import encode
from adclient.schemas import NAME_PATTERN as PARAM_NAME
from adclient.specs import Bound, link_mass
from tests.client.design_strategies import multi_structure_spaces, single_structure_spaces


def unit_vectors(dim: int) -> st.SearchStrategy[list[float]]:
    return st.lists(st.floats(0.0, 1.0), min_size=dim, max_size=dim)


@settings(max_examples=40, deadline=None)
@given(single_structure_spaces(), st.data())
def test_identity_round_trip(body: dict[str, Any], data: st.DataObject) -> None:
    space = DesignSpace.model_validate(body)
    representation = identity_representation(space)
    layout = spec_layout(space)
    assert representation.bounds == [[0.0] * layout.size, [1.0] * layout.size]
    vector = data.draw(unit_vectors(layout.size))
    design = decode(space, representation, vector)
    assert encode(space, representation, design) == pytest.approx(vector, abs=1e-9)
    # the readable params carry the same specs
    params = design_params(design)
    assert encode(space, representation, params) == pytest.approx(vector, abs=1e-9)


@settings(max_examples=40, deadline=None)
@given(single_structure_spaces(), st.data())
def test_decoded_design_follows_the_space(body: dict[str, Any], data: st.DataObject) -> None:
    space = DesignSpace.model_validate(body)
    representation = identity_representation(space)
    vector = data.draw(unit_vectors(len(representation.spec_names)))
    design = decode(space, representation, vector)
    (structure,) = space.tree_structures()
    assert sorted(design.edges()) == sorted(structure)
    assert {link.name for link in design.links} == {i.name for i in space.instances}
    children = {child for _, child in structure}
    assert design.root not in children
    for link in design.links:
        instance = space.instance(link.name)
        assert link.shape == space.parts[instance.part].shape
        given = space.mass_spec(link.name)
        for spec in ("length", "radius", given):
            expected = space.part_spec(link.name, spec)
            value = getattr(link, spec)
            if isinstance(expected, Bound):
                assert expected.low - 1e-12 <= value <= expected.high + 1e-12
            else:
                assert value == expected
        if given == "density":  # the mass is derived: density x the shape's volume
            assert link.density is not None
            side = 2 * link.radius
            area = side * side if link.shape == "box" else math.pi * link.radius**2
            assert link.mass == pytest.approx(link.density * area * link.length, rel=1e-12)
        else:
            assert link.density is None
    for joint in design.joints:
        theta, phi = joint.axis_theta, joint.axis_phi
        expected_axis = (
            math.sin(theta) * math.cos(phi),
            math.sin(theta) * math.sin(phi),
            math.cos(theta),
        )
        assert joint.axis == pytest.approx(expected_axis)
        assert math.isclose(sum(c * c for c in joint.axis), 1.0)
        assert joint.lower <= joint.upper
        for spec in ("axis_theta", "axis_phi", "position", "lower", "upper", "effort"):
            expected = space.joint_spec(joint.child, spec)
            value = getattr(joint, spec)
            if isinstance(expected, Bound):
                assert expected.low - 1e-12 <= value <= expected.high + 1e-12
            else:
                assert value == expected


@settings(max_examples=20, deadline=None)
@given(single_structure_spaces(), st.data())
def test_params_are_readable_json(body: dict[str, Any], data: st.DataObject) -> None:
    space = DesignSpace.model_validate(body)
    representation = identity_representation(space)
    vector = data.draw(unit_vectors(len(representation.spec_names)))
    params = design_params(decode(space, representation, vector))
    assert json.loads(json.dumps(params)) == params
    assert all(re.fullmatch(PARAM_NAME, key) for key in params)
    edges = space.tree_structures()[0]
    assert sorted(params["structure"].split(",")) == sorted(f"{p}-{c}" for p, c in edges)
    for name in representation.spec_names:  # every searched spec is shown
        assert name in params


def test_vectors_are_clipped_and_checked() -> None:
    space = DesignSpace.model_validate(
        {
            "type": "design",
            "parts": {"link": {"length": {"low": 0.2, "high": 0.6}}},
            "instances": [{"name": "a", "part": "link"}, {"name": "b", "part": "link"}],
            "structures": [[["a", "b"]]],
        }
    )
    representation = identity_representation(space)
    assert representation.spec_names == [
        "a.length",
        "b.length",
        "b.joint.axis_theta",
        "b.joint.axis_phi",
    ]
    design = decode(space, representation, [-1.0, 2.0, 0.5, 0.5])
    assert [link.length for link in design.links] == [0.2, 0.6]
    with pytest.raises(ValueError, match="vector has 2 values, the search space has 4"):
        decode(space, representation, [0.5, 0.5])
    with pytest.raises(ValueError, match="non-finite"):
        decode(space, representation, [0.5, math.nan, 0.5, 0.5])
    with pytest.raises(ValueError, match=r"'a\.length' = 0\.9 lies outside"):
        encode(
            space,
            representation,
            {"a.length": 0.9, "b.length": 0.3, "b.joint.axis_theta": 1.0, "b.joint.axis_phi": 1.0},
        )
    with pytest.raises(ValueError, match=r"'b\.joint\.axis_phi' is missing"):
        encode(space, representation, {"a.length": 0.3, "b.length": 0.3, "b.joint.axis_theta": 1.0})
    other = DesignSpace.model_validate(space.model_dump() | {"parts": {"link": {"length": 0.3}}})
    with pytest.raises(ValueError, match="does not belong to this space"):
        decode(other, representation, [0.5, 0.5, 0.5, 0.5])


def test_identity_needs_one_structure() -> None:
    space = DesignSpace.model_validate(
        {
            "type": "design",
            "parts": {"link": {}},
            "instances": [{"name": n, "part": "link"} for n in "abc"],
            "structures": "all",
        }
    )
    with pytest.raises(ValueError, match="needs one structure, the space has 3"):
        identity_representation(space)


# -- fused representations (built by the service) -------------------------------------

representation_module = pytest.importorskip("adservice.representation")


@settings(max_examples=10, deadline=None)
@given(multi_structure_spaces(), st.data())
def test_fused_reference_designs_decode_to_their_structure(
    body: dict[str, Any], data: st.DataObject
) -> None:
    space = DesignSpace.model_validate({**body, "encoding": "fused"})
    representation = representation_module.build_representation(space)
    assert representation.kind == "fused"
    coords = np.asarray(representation.ref_coords)
    low, high = np.asarray(representation.bounds)
    assert np.all(coords >= low) and np.all(coords <= high)
    for point, structure in zip(coords, representation.ref_structure, strict=True):
        design = decode(space, representation, point.tolist())
        assert design.structure_index == structure
        assert sorted(design.edges()) == sorted(space.tree_structures()[structure])
        # and encoding that design comes back to a vector of the same design
        again = decode(space, representation, encode(space, representation, design))
        assert again.structure_index == structure
        assert _close(again, design)
    # any vector in the box decodes to one of the candidate structures, specs in bounds
    layout = spec_layout(space)
    vector = [data.draw(st.floats(lo, hi)) for lo, hi in zip(low, high, strict=True)]
    design = decode(space, representation, vector)
    assert 0 <= design.structure_index < len(space.tree_structures())
    for link in design.links:
        key = f"{link.name}.length"
        if key in layout.names:
            k = layout.names.index(key)
            assert layout.low[k] - 1e-12 <= link.length <= layout.high[k] + 1e-12


@settings(max_examples=10, deadline=None)
@given(multi_structure_spaces(), st.data())
def test_mixed_vectors_decode_by_identity(body: dict[str, Any], data: st.DataObject) -> None:
    """The default for several structures: any vector in the box is a design whose
    specs are the vector's own (no map, no clipping), and encoding it is exact."""
    space = DesignSpace.model_validate(body)
    representation = representation_module.build_representation(space)
    assert representation.kind == "mixed"
    layout = spec_layout(space)
    count = len(space.tree_structures())
    low, high = np.asarray(representation.bounds)
    assert low[0] == -0.5 and high[0] == count - 0.5
    vector = [data.draw(st.floats(lo, hi)) for lo, hi in zip(low, high, strict=True)]
    design = decode(space, representation, vector)
    assert design.structure_index == min(max(math.floor(vector[0] + 0.5), 0), count - 1)
    values = design_params(design)
    used = layout.used_slots(space.tree_structures()[design.structure_index])
    for k, key in enumerate(layout.names):
        if used[k] and layout.log[k]:
            low, high = math.log(layout.low[k]), math.log(layout.high[k])
            expected = math.exp(low + vector[1 + k] * (high - low))
            assert values[key] == pytest.approx(expected, rel=1e-12, abs=1e-12)
        elif used[k]:
            expected = layout.low[k] + vector[1 + k] * (layout.high[k] - layout.low[k])
            assert values[key] == pytest.approx(expected, rel=1e-12, abs=1e-12)
    again = encode(space, representation, design)
    assert again[0] == design.structure_index
    np.testing.assert_allclose(np.asarray(again[1:])[used], np.asarray(vector[1:])[used], atol=1e-9)
    assert decode(space, representation, again) == design


def _close(a: Any, b: Any) -> bool:
    first, second = a.model_dump(), b.model_dump()
    links = all(
        x["name"] == y["name"] and math.isclose(x["length"], y["length"], abs_tol=1e-9)
        for x, y in zip(first["links"], second["links"], strict=True)
    )
    joints = all(
        math.isclose(x["axis_theta"], y["axis_theta"], abs_tol=1e-9)
        and math.isclose(x["axis_phi"], y["axis_phi"], abs_tol=1e-9)
        for x, y in zip(first["joints"], second["joints"], strict=True)
    )
    return links and joints


LOG_SPACE: dict[str, Any] = {
    "type": "design",
    "parts": {
        "link": {
            "length": {"low": 0.2, "high": 0.6},
            "mass": {"low": 0.01, "high": 100.0, "log": True},
        }
    },
    "joint": {"effort": {"low": 0.5, "high": 50.0, "log": True}},
    "instances": [{"name": "a", "part": "link"}, {"name": "b", "part": "link"}],
    "structures": [[["a", "b"]]],
}


def test_a_log_spec_maps_its_slot_log_uniformly() -> None:
    space = DesignSpace.model_validate(LOG_SPACE)
    representation = identity_representation(space)
    layout = spec_layout(space)
    assert representation.spec_names == [
        "a.length",
        "a.mass",
        "b.length",
        "b.mass",
        "b.joint.axis_theta",
        "b.joint.axis_phi",
        "b.joint.effort",
    ]
    assert layout.log.tolist() == [False, True, False, True, False, False, True]
    # the representation keeps physical ranges; the scale comes from the space
    assert representation.spec_low[1] == 0.01 and representation.spec_high[1] == 100.0

    def params_at(u: float) -> dict[str, Any]:
        return design_params(decode(space, representation, [u] * layout.size))

    ends = params_at(0.0), params_at(1.0)
    # the ends are the bounds exactly, on either scale
    assert [p["a.mass"] for p in ends] == [0.01, 100.0]
    assert [p["b.joint.effort"] for p in ends] == [0.5, 50.0]
    assert [p["a.length"] for p in ends] == [0.2, 0.6]
    for u in (0.25, 0.5, 0.75):
        params = params_at(u)
        assert params["a.mass"] == pytest.approx(0.01 * 10_000**u, rel=1e-12)
        assert params["b.joint.effort"] == pytest.approx(0.5 * 100**u, rel=1e-12)
        assert params["a.length"] == pytest.approx(0.2 + 0.4 * u, rel=1e-12)
    middle = params_at(0.5)
    assert middle["a.mass"] == pytest.approx(1.0)  # the geometric mean, not 50.005
    # a vector outside [0, 1] is clipped to the bounds, as a linear spec's is
    clipped = design_params(decode(space, representation, [-3.0, 4.0, 0.5, -1.0, 0.5, 0.5, 9.0]))
    assert (clipped["a.mass"], clipped["b.mass"], clipped["b.joint.effort"]) == (100.0, 0.01, 50.0)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(0.0, 1.0), min_size=7, max_size=7))
def test_a_log_spec_round_trips(vector: list[float]) -> None:
    space = DesignSpace.model_validate(LOG_SPACE)
    representation = identity_representation(space)
    design = decode(space, representation, vector)
    for link in design.links:
        assert 0.01 <= link.mass <= 100.0
    assert 0.5 <= design.joints[0].effort <= 50.0
    again = encode(space, representation, design)
    assert again == pytest.approx(vector, abs=1e-12)
    # what a user hands back (the readable params) decodes to the same design, bit for bit
    params = design_params(design)
    assert decode(space, representation, encode(space, representation, params)) == design


def test_a_log_spec_is_encoded_from_its_value() -> None:
    space = DesignSpace.model_validate(LOG_SPACE)
    representation = identity_representation(space)
    specs = {
        "a.length": 0.2,
        "a.mass": 1.0,
        "b.length": 0.6,
        "b.mass": 0.1,
        "b.joint.axis_theta": 0.0,
        "b.joint.axis_phi": math.pi,
        "b.joint.effort": 5.0,
    }
    vector = encode(space, representation, specs)
    assert vector == pytest.approx([0.0, 0.5, 1.0, 0.25, 0.0, 1.0, 0.5], abs=1e-12)
    with pytest.raises(ValueError, match=r"'a\.mass' = 0\.001 lies outside \[0\.01, 100\.0\]"):
        encode(space, representation, specs | {"a.mass": 0.001})
    with pytest.raises(ValueError, match=r"'b\.joint\.effort' = -1\.0 lies outside"):
        encode(space, representation, specs | {"b.joint.effort": -1.0})


# ------------------------------------------------------------ mass from density

DENSE_SPACE: dict[str, Any] = {
    "type": "design",
    "parts": {
        "link": {
            "length": {"low": 0.2, "high": 0.6},
            "radius": {"low": 0.01, "high": 0.05, "log": True},
            "density": 2700.0,
        },
        "plate": {"shape": "box", "length": 0.1, "radius": 0.05, "density": 1240.0},
    },
    "joint": {"axis_theta": 1.5707963267948966, "axis_phi": 0.0},
    "instances": [
        {"name": "a", "part": "link"},
        {"name": "b", "part": "link", "overrides": {"density": {"low": 500.0, "high": 8000.0}}},
        {"name": "c", "part": "link", "overrides": {"mass": 0.25}},
        {"name": "d", "part": "plate"},
    ],
    "structures": [[["a", "b"], ["b", "c"], ["b", "d"]]],
}


def test_a_density_gives_the_mass_of_a_solid_cylinder() -> None:
    space = DesignSpace.model_validate(DENSE_SPACE)
    representation = identity_representation(space)
    assert representation.spec_names == [
        "a.length",
        "a.radius",
        "b.length",
        "b.radius",
        "b.density",
        "c.length",
        "c.radius",
    ]
    for vector in ([0.0] * 7, [1.0] * 7, [0.3, 0.7, 0.1, 0.9, 0.5, 0.2, 0.6]):
        design = decode(space, representation, vector)
        links = {link.name: link for link in design.links}
        a, b, c, d = links["a"], links["b"], links["c"], links["d"]
        assert a.density == 2700.0
        assert a.mass == link_mass("cylinder", a.length, a.radius, 2700.0)
        assert a.mass == pytest.approx(2700.0 * math.pi * a.radius**2 * a.length, rel=1e-15)
        assert b.density is not None and 500.0 <= b.density <= 8000.0
        assert b.mass == pytest.approx(b.density * math.pi * b.radius**2 * b.length, rel=1e-15)
        assert (c.mass, c.density) == (0.25, None)  # its override: a mass of its own
        assert d.mass == pytest.approx(1240.0 * (2 * 0.05) ** 2 * 0.1, rel=1e-15)  # a box
    ends = [decode(space, representation, [u] * len(representation.spec_names)) for u in (0, 1)]
    assert ends[0].links[0].mass == pytest.approx(2700.0 * math.pi * 0.01**2 * 0.2, rel=1e-15)
    # longer or thicker links weigh more
    assert ends[1].links[0].mass / ends[0].links[0].mass == pytest.approx(25 * 3, rel=1e-12)


def test_params_show_the_derived_mass_and_round_trip() -> None:
    space = DesignSpace.model_validate(DENSE_SPACE)
    representation = identity_representation(space)
    vector = [0.3, 0.7, 0.1, 0.9, 0.5, 0.2, 0.6]
    design = decode(space, representation, vector)
    params = design_params(design)
    a = design.links[0]
    keys = [key for key in params if key.startswith("a.")]
    assert keys == ["a.length", "a.radius", "a.mass", "a.density"]
    assert params["a.mass"] == a.mass and params["a.density"] == 2700.0
    assert "c.density" not in params and params["c.mass"] == 0.25
    # a design's params, as the server shows them, encode back to the same design
    again = encode(space, representation, params)
    assert decode(space, representation, again) == design
    assert again == pytest.approx(vector, abs=1e-12)
    assert encode(space, representation, design) == pytest.approx(vector, abs=1e-12)
    # the derived mass may be left out; a mass of one's own is not this design
    without = {key: value for key, value in params.items() if not key.endswith(".mass")}
    assert decode(space, representation, encode(space, representation, without)) == design
    with pytest.raises(ValueError, match=r"spec 'a\.mass' = 9\.0 is not this link's mass"):
        encode(space, representation, params | {"a.mass": 9.0})
    with pytest.raises(ValueError, match=r"'b\.mass' = 'heavy' is not this link's mass"):
        encode(space, representation, params | {"b.mass": "heavy"})
    # a link whose mass is its own spec ignores a given mass, as before
    assert encode(space, representation, params | {"c.mass": 3.0}) == again
    with pytest.raises(ValueError, match=r"spec 'b\.density' is missing"):
        encode(space, representation, {k: v for k, v in params.items() if k != "b.density"})


@settings(max_examples=60, deadline=None)
@given(unit_vectors(7))
def test_a_density_space_round_trips_bit_for_bit(vector: list[float]) -> None:
    space = DesignSpace.model_validate(DENSE_SPACE)
    representation = identity_representation(space)
    design = decode(space, representation, vector)
    params = design_params(design)
    assert json.loads(json.dumps(params)) == params
    assert decode(space, representation, encode(space, representation, params)) == design
    assert decode(space, representation, encode(space, representation, design)) == design


def test_a_spaces_layout_is_computed_once_shared_read_only_and_dropped_with_it() -> None:
    """A server decodes and encodes every trial of a study through its one space: the
    layout (3 ms of a design space's free specs) is the same object each time, its
    arrays cannot be changed through one caller, an equal space of its own gets its own,
    and it goes with its space."""
    body = {
        "type": "design",
        "parts": {"link": {"length": {"low": 0.1, "high": 0.5}, "radius": 0.04}},
        "instances": [{"name": "a", "part": "link"}, {"name": "b", "part": "link"}],
        "structures": [[["a", "b"]]],
    }
    space, twin = DesignSpace.model_validate(body), DesignSpace.model_validate(body)
    layout = spec_layout(space)
    assert spec_layout(space) is layout
    decode(space, identity_representation(space), [0.5] * layout.size)
    assert spec_layout(space) is layout
    assert spec_layout(twin) is not layout and spec_layout(twin).names == layout.names
    for array in (layout.low, layout.high, layout.log):
        with pytest.raises(ValueError, match="read-only"):
            array[0] = array[0]
    collected = weakref.ref(layout)
    del space, layout
    gc.collect()
    assert collected() is None
