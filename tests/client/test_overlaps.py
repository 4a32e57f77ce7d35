"""Links that interpenetrate at the rest pose are found from the design's geometry alone
(``adclient.overlaps``): a child inside its parent, siblings through each other, a link
folded back through another; what touches at a joint is normal (issue 60)."""

from __future__ import annotations

import math

import pytest

from adclient.designs import Design, Joint, Link
from adclient.overlaps import MAX_SAMPLES_ALONG, Overlap, overlap_reason, rest_overlaps

HALF_PI = math.pi / 2


def design(
    links: dict[str, tuple[str, float, float]],
    joints: list[tuple[str, str, float, tuple[float, float, float]]],
) -> Design:
    """Links as name -> (shape, length, radius); joints as (parent, child, position,
    (roll, pitch, yaw) offset), each about y."""
    children = {child for _, child, _, _ in joints}
    return Design(
        structure_index=0,
        root=next(name for name in links if name not in children),
        links=[
            Link(name=name, shape=shape, length=length, radius=radius, mass=1.0)
            for name, (shape, length, radius) in links.items()
        ],
        joints=[
            Joint(
                name=f"{parent}_{child}",
                parent=parent,
                child=child,
                axis=(0.0, 1.0, 0.0),
                axis_theta=HALF_PI,
                axis_phi=HALF_PI,
                position=position,
                lower=-HALF_PI,
                upper=HALF_PI,
                effort=10.0,
                velocity=5.0,
                offset_roll=roll,
                offset_pitch=pitch,
                offset_yaw=yaw,
            )
            for parent, child, position, (roll, pitch, yaw) in joints
        ],
    )


STRAIGHT = (0.0, 0.0, 0.0)
TORSO = {"torso": ("box", 0.4, 0.05)}
LEGS = {"left": ("cylinder", 0.2, 0.02), "right": ("cylinder", 0.2, 0.02)}


def pairs(found: list[Overlap]) -> set[frozenset[str]]:
    return {frozenset((overlap.first, overlap.second)) for overlap in found}


def test_side_legs_without_offset_roll_lie_inside_the_torso_and_through_each_other() -> None:
    """The issue's space: legs set on the torso's side (mid-way) but not turned out, so
    at rest both run along the torso's axis, inside its box."""
    hidden = design(
        TORSO | LEGS, [("torso", "left", 0.5, STRAIGHT), ("torso", "right", 0.5, STRAIGHT)]
    )
    found = rest_overlaps(hidden)
    assert pairs(found) == {
        frozenset(("torso", "left")),
        frozenset(("torso", "right")),
        frozenset(("left", "right")),
    }
    assert all(overlap.depth > 0.01 for overlap in found)
    reason = overlap_reason(found)
    assert reason.startswith("links interpenetrate at the rest pose: ")
    assert "torso and left" in reason and "left and right" in reason
    # turned out of the torso's sides (offset_roll) they only meet it at their joints
    turned = design(
        TORSO | LEGS,
        [("torso", "left", 0.5, (-HALF_PI, 0.0, 0.0)), ("torso", "right", 0.5, (HALF_PI, 0, 0))],
    )
    assert rest_overlaps(turned) == []


def test_a_chain_touching_at_its_joints_is_normal() -> None:
    chain = {name: ("cylinder", 0.4, 0.04) for name in "abc"}
    assert (
        rest_overlaps(design(chain, [("a", "b", 1.0, STRAIGHT), ("b", "c", 1.0, STRAIGHT)])) == []
    )
    # a bent elbow at rest: the child leaves its parent's end sideways, sharing its corner
    bent = design(chain, [("a", "b", 1.0, (HALF_PI, 0, 0)), ("b", "c", 1.0, (0, HALF_PI, 0))])
    assert rest_overlaps(bent) == []
    # boxes and capsules alike: a leg turned down off a box torso's end
    leg = {"leg": ("capsule", 0.2, 0.03)}
    assert rest_overlaps(design(TORSO | leg, [("torso", "leg", 1.0, (0, HALF_PI, 0))])) == []


def test_a_child_inside_its_parent_or_folded_back_through_it_is_found() -> None:
    chain = {name: ("cylinder", 0.4, 0.04) for name in "abc"}
    inside = design(chain, [("a", "b", 0.25, STRAIGHT), ("b", "c", 1.0, STRAIGHT)])
    assert pairs(rest_overlaps(inside)) == {frozenset(("a", "b"))}
    folded = design(chain, [("a", "b", 1.0, STRAIGHT), ("b", "c", 1.0, (0.0, math.pi, 0.0))])
    assert pairs(rest_overlaps(folded)) == {frozenset(("b", "c"))}
    # a capsule set across a box, through it
    rod = {"rod": ("capsule", 0.06, 0.02)}
    across = design(TORSO | rod, [("torso", "rod", 0.5, (HALF_PI, 0.0, 0.0))])
    assert rest_overlaps(across) == []  # leaving the torso's axis sideways: at its joint
    through = design(TORSO | rod, [("torso", "rod", 0.2, STRAIGHT)])
    assert pairs(rest_overlaps(through)) == {frozenset(("torso", "rod"))}


def test_siblings_along_one_line_overlap_and_splayed_ones_meet_at_their_joint() -> None:
    star = {name: ("cylinder", 0.4, 0.04) for name in "abcd"}
    along = design(star, [("a", child, 1.0, STRAIGHT) for child in "bcd"])
    assert pairs(rest_overlaps(along)) == {
        frozenset(pair) for pair in (("b", "c"), ("b", "d"), ("c", "d"))
    }
    splayed = design(
        star,
        [
            ("a", "b", 1.0, STRAIGHT),
            ("a", "c", 1.0, (HALF_PI, 0.0, 0.0)),
            ("a", "d", 1.0, (-HALF_PI, 0.0, 0.0)),
        ],
    )
    assert rest_overlaps(splayed) == []
    # siblings a few degrees apart lie through each other beyond their shared joint
    three = {name: star[name] for name in "abc"}
    close = design(three, [("a", "b", 1.0, STRAIGHT), ("a", "c", 1.0, (0.1, 0.0, 0.0))])
    assert pairs(rest_overlaps(close)) == {frozenset(("b", "c"))}


def test_links_that_only_touch_are_within_the_tolerance() -> None:
    """Two legs side by side, their surfaces 1 mm apart, then 1 mm into each other."""
    for gap, overlapping in ((0.001, False), (-0.004, True)):
        spacing = (2 * 0.02 + gap) / 0.4  # the legs' joints along the torso's axis
        sideways = (-HALF_PI, 0.0, 0.0)
        legs = design(
            TORSO | LEGS,
            [("torso", "left", 0.5, sideways), ("torso", "right", 0.5 + spacing, sideways)],
        )
        found = pairs(rest_overlaps(legs)) - {
            frozenset(("torso", "left")),
            frozenset(("torso", "right")),
        }
        assert (found == {frozenset(("left", "right"))}) is overlapping, (gap, found)


def test_the_most_overlapping_pairs_are_named_first_and_the_rest_counted() -> None:
    many = {name: ("cylinder", 0.3, 0.03) for name in "abcdefgh"}
    star = design(many, [("a", child, 1.0, STRAIGHT) for child in "bcdefgh"])
    found = rest_overlaps(star)
    assert len(found) == 21  # every pair of the seven coincident children
    assert [overlap.depth for overlap in found] == sorted(
        (overlap.depth for overlap in found), reverse=True
    )
    assert overlap_reason(found).endswith(" and 15 more pairs")


@pytest.mark.parametrize("length", [0.05, 3.0])
def test_a_links_samples_are_bounded_whatever_its_length(length: float) -> None:
    import numpy as np

    from adclient.overlaps import _shape

    for shape in ("box", "cylinder", "capsule"):
        link = Link(name="a", shape=shape, length=length, radius=0.04, mass=1.0)
        points = _shape(link, np.eye(3), np.zeros(3)).samples()
        assert 0 < len(points) <= (MAX_SAMPLES_ALONG + 2) * 17
