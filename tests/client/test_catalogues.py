"""Catalogues (issue 28): a joint or part that chooses from a catalogue is one of its
components, its specs the component's, related to the others by their entries; the
choice round-trips through params; bad catalogues and choices are refused by name."""

from __future__ import annotations

import copy
import re
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from pydantic import ValidationError

from adclient.catalogues import choice_slots, coordinate, coordinates, nearest
from adclient.decode import decode, design_catalogue_totals, design_params, identity_representation
from adclient.design import DesignSpace
from adclient.encode import encode

ROOT = Path(__file__).resolve().parents[2]
ARM = yaml.safe_load((ROOT / "examples" / "catalogue-arm.yaml").read_text(encoding="utf-8"))
SERVOS = ARM["space"]["catalogues"]["servos"]


def _arm(**changes: Any) -> dict[str, Any]:
    space = copy.deepcopy(ARM["space"])
    space.update(changes)
    return space


def test_the_search_moves_through_an_embedding_of_the_entries() -> None:
    """The servos' effort, mass and price rise together (velocity falls): one principal
    component holds over 90% of their spread, so each joint searches one coordinate,
    along which the servos lie from the strongest to the weakest."""
    (slot,) = choice_slots(SERVOS)
    places = {name: place[0] for name, place in coordinates(SERVOS).items()}
    assert (slot.low, slot.high) == (min(places.values()), max(places.values()))
    by_place = sorted(SERVOS, key=places.__getitem__)
    assert {by_place[0], by_place[-1]} == {"pm42", "xl330"}  # strongest, weakest at the ends
    space = DesignSpace.model_validate(ARM["space"])
    names = [key for key, _ in space.free_specs()]
    assert names == ["b.length", "c.length", "d.length"] + [f"{j}.joint.choice.0" for j in "bcd"]


def test_entries_that_do_not_go_together_keep_more_dimensions() -> None:
    """Fast-and-weak against slow-and-strong, and price unrelated to both: two or
    three coordinates, and every motor its own nearest."""
    motors = {
        "a": {"effort": 1.0, "velocity": 9.0, "cost": 300.0},
        "b": {"effort": 9.0, "velocity": 1.0, "cost": 300.0},
        "c": {"effort": 1.0, "velocity": 1.0, "cost": 10.0},
        "d": {"effort": 9.0, "velocity": 9.0, "cost": 10.0},
    }
    assert len(choice_slots(motors)) >= 2
    for name in motors:
        point = {slot.key: coordinate(motors, name, slot.key) for slot in choice_slots(motors)}
        assert nearest(motors, point) == name


def test_each_component_decodes_from_its_place_and_similar_ones_are_near() -> None:
    places = coordinates(SERVOS)
    for name, place in places.items():
        assert nearest(SERVOS, {str(d): v for d, v in enumerate(place)}) == name
    # servos that differ only in price lie next to each other
    for a, b in (("xm430", "xh430"), ("xm540", "xh540")):
        others = {k: v for k, v in places.items() if k != a}
        closest = min(others, key=lambda k: abs(others[k][0] - places[a][0]))
        assert closest == b


@pytest.mark.parametrize("seed", range(5))
def test_designs_carry_their_components_specs_and_round_trip(seed: int) -> None:
    space = DesignSpace.model_validate(ARM["space"])
    representation = identity_representation(space)
    rng = np.random.default_rng(seed)
    chosen: Counter[str] = Counter()
    for _ in range(200):
        design = decode(space, representation, rng.random(len(representation.bounds[0])).tolist())
        params = design_params(design)
        for joint in "bcd":
            name = params[f"{joint}.joint.choice"]
            chosen[name] += 1
            assert params[f"{joint}.joint.effort"] == SERVOS[name]["effort"]
            assert params[f"{joint}.joint.velocity"] == SERVOS[name]["velocity"]
        vector = encode(space, representation, params)
        assert decode(space, representation, vector) == design
        totals = design_catalogue_totals(space, design)
        names = [params[f"{joint}.joint.choice"] for joint in "bcd"]
        assert totals["servos.cost"] == pytest.approx(sum(SERVOS[n]["cost"] for n in names))
        assert totals["servos.mass"] == pytest.approx(sum(SERVOS[n]["mass"] for n in names))
    assert set(chosen) == set(SERVOS), chosen  # every servo is reachable


def test_a_given_spec_must_be_the_components_and_the_choice_a_component() -> None:
    space = DesignSpace.model_validate(ARM["space"])
    representation = identity_representation(space)
    design = decode(space, representation, [0.5] * len(representation.bounds[0]))
    params = design_params(design)
    name = params["b.joint.choice"]
    with pytest.raises(ValueError, match=rf"'b.joint.effort' = 99.0 .* component '{name}'"):
        encode(space, representation, {**params, "b.joint.effort": 99.0})
    with pytest.raises(ValueError, match=r"'nope' is no component of catalogue 'servos'"):
        encode(space, representation, {**params, "b.joint.choice": "nope"})
    with pytest.raises(ValueError, match=r"'b.joint.choice' is missing"):
        encode(space, representation, {k: v for k, v in params.items() if k != "b.joint.choice"})
    other = next(n for n in SERVOS if n != name)
    moved = {**params, "b.joint.choice": other}
    del moved["b.joint.effort"], moved["b.joint.velocity"]
    assert (
        design_params(decode(space, representation, encode(space, representation, moved)))[
            "b.joint.choice"
        ]
        == other
    )


def test_a_part_chooses_stock_tubes() -> None:
    tubes = {
        "t16": {"radius": 0.008, "density": 2700.0},
        "t25": {"radius": 0.0125, "density": 2700.0},
    }
    space = DesignSpace.model_validate(
        _arm(
            catalogues={"tubes": tubes},
            parts={
                "base": ARM["space"]["parts"]["base"],
                "link": {"length": {"low": 0.1, "high": 0.4}, "density": 1.0, "choose": "tubes"},
            },
            joint={k: v for k, v in ARM["space"]["joint"].items() if k != "choose"},
        )
    )
    representation = identity_representation(space)
    assert [key for key, _ in space.free_specs() if ".choice." in key] == [
        "b.choice.0",
        "c.choice.0",
        "d.choice.0",
    ]
    slot = {"b.choice.0": 0.9, "c.choice.0": 0.1, "d.choice.0": 0.9}
    vector = [slot.get(name, 0.3) for name in representation.spec_names]
    design = decode(space, representation, vector)
    links = {link.name: link for link in design.links}
    assert (links["b"].choice, links["c"].choice) == ("t25", "t16")
    assert links["b"].radius == 0.0125 and links["b"].density == 2700.0
    # issue 36: the part's JSON (what the server stores and workers read) dropped its
    # choose, so a stored study's slots differed from its representation's and every
    # ask failed ("the representation does not belong to this space")
    stored = DesignSpace.model_validate(space.model_dump(mode="json"))
    assert stored.parts["link"].choose == "tubes"
    assert stored.free_specs() == space.free_specs()
    assert decode(stored, representation, vector) == design


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (
            {"joint": {"choose": "motors"}},
            r"joint.choose: unknown catalogue 'motors' \(catalogues: servos\)",
        ),
        (
            {"catalogues": {"servos": {}}},
            r"catalogues.servos: a catalogue needs at least one component",
        ),
        (
            {"catalogues": {"servos": {"a": {"effort": 1.0}, "b": {"effort": 2.0, "cost": 3.0}}}},
            r"catalogues.servos.b: entries \['cost', 'effort'\] differ from a's \['effort'\]",
        ),
        (
            {"catalogues": {"servos": {"a": {"effort": -1.0}}}},
            r"catalogues.servos.a.effort: must be > 0",
        ),
        (
            {"catalogues": {"servos": {"a": {"lower": 1.0, "upper": 0.5}}}},
            r"catalogues.servos.a: lower \(1.0\) exceeds upper \(0.5\)",
        ),
        ({"catalogues": {"servos": {"a b": {"effort": 1.0}}}}, r"component name 'a b' must match"),
        (
            {"spec_constraints": [{"terms": {"b.joint.effort": 1.0}, "op": "<=", "bound": 5.0}]},
            r"'b.joint.effort' is set by the component chosen from a catalogue",
        ),
    ],
)
def test_bad_catalogues_are_refused_by_name(change: dict[str, Any], message: str) -> None:
    with pytest.raises(ValidationError) as caught:
        DesignSpace.model_validate(_arm(**change))
    assert re.search(message, str(caught.value)), str(caught.value)


TUBES = {"t16": {"radius": 0.008, "density": 2700.0}, "t25": {"radius": 0.0125, "density": 2700.0}}


@pytest.mark.parametrize(
    ("instance", "message"),
    [
        (
            {"joint_overrides": {"effort": 3.0}},
            r"instances\[1\] \('b'\): joint_overrides effort: the component chosen from "
            r"catalogue 'servos' sets them",
        ),
        (
            {"overrides": {"radius": 0.01}},
            r"\('b'\): overrides radius: the component chosen from catalogue 'tubes' sets them",
        ),
        (
            {"overrides": {"mass": 0.2}},
            r"\('b'\): its mass is given by mass \(its override\), but catalogue 'tubes' "
            r"sets density",
        ),
    ],
    ids=["joint override", "part override", "other mass spec"],
)
def test_an_override_of_what_a_component_sets_is_refused(
    instance: dict[str, Any], message: str
) -> None:
    """Issue 36: the component's value won unseen (an overridden effort or radius was
    ignored), or an override of the other mass spec left the catalogue's unused and
    the params' mass refused on enqueue."""
    space = _arm(catalogues={**ARM["space"]["catalogues"], "tubes": TUBES})
    space["parts"]["link"]["choose"] = "tubes"
    space["instances"][1].update(instance)
    stored = DesignSpace.model_validate(space)  # as a study stored before the rule loads
    with pytest.raises(ValueError) as caught:
        stored.check_at_creation()
    assert re.search(message, str(caught.value)), str(caught.value)


def test_a_space_without_catalogues_serialises_as_before() -> None:
    plain = DesignSpace.model_validate(_arm(catalogues={}, joint={"axis_theta": 1.0}))
    dumped = plain.model_dump(mode="json")
    assert "choose" not in dumped["joint"]
    assert all("choose" not in part for part in dumped["parts"].values())
    representation = identity_representation(plain)
    design = decode(plain, representation, [0.5] * len(representation.bounds[0]))
    assert all("choice" not in joint for joint in design.model_dump(mode="json")["joints"])
