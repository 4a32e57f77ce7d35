"""Tied instances: an instance that says ``same_as: b`` has b's specs and b's joint,
searched once (a symmetric robot's left and right legs), optionally mirrored.

A mirror is a reflection across the plane ``x = 0`` or ``y = 0`` of the frames (the
links run along z, which both planes contain, so a mirrored limb has the same
shape). Mirroring a revolute joint reflects its motion: the joint turns about
``-M a`` (a rotation axis is a pseudo-vector) by the same angle, so the limits stay
as they are and only the axis angles change (``mirrored_angle``). Ties chain
(``c same_as b same_as a``) and their mirrors compose: two different mirrors make a
half turn about z.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Literal

Mirror = Literal["x", "y"]


@dataclass(frozen=True)
class Tie:
    """Where a tied instance's specs come from: the untied ``source`` at the end of
    its ``same_as`` chain, reflected across x = 0 (``flip_x``) and/or y = 0
    (``flip_y``)."""

    source: str
    flip_x: bool = False
    flip_y: bool = False
    own: frozenset[str] = frozenset()
    """The joint specs the tied instance gives itself (``joint_overrides.position``:
    where it sits on its parent), which are not its source's."""


def resolve_ties(
    same_as: Mapping[str, str | None],
    mirror: Mapping[str, Mirror | None],
    own: Mapping[str, Iterable[str]] | None = None,
) -> dict[str, Tie]:
    """Every tied instance's Tie (untied instances are absent). ``same_as`` maps every
    instance, in order, to the instance it names or None; ``own`` to the joint specs
    it gives itself. A ValueError names an unknown instance or a cycle."""
    ties: dict[str, Tie] = {}
    for name, target in same_as.items():
        if target is None:
            continue
        chain = [name]
        flip_x = flip_y = False
        current: str | None = name
        while current is not None and same_as.get(current) is not None:
            plane = mirror.get(current)
            flip_x ^= plane == "x"
            flip_y ^= plane == "y"
            following = same_as[current]
            assert following is not None
            if following not in same_as:
                raise ValueError(
                    f"instance {current!r}: same_as names unknown instance {following!r} "
                    f"(instances: {', '.join(sorted(same_as))})"
                )
            if following in chain:
                cycle = " -> ".join([*chain[chain.index(following) :], following])
                raise ValueError(
                    f"instances: same_as forms a cycle ({cycle}); one instance of a tie "
                    "must hold the specs (leave same_as out there)"
                )
            chain.append(following)
            current = following
        mine = frozenset((own or {}).get(name, ()))
        ties[name] = Tie(source=chain[-1], flip_x=flip_x, flip_y=flip_y, own=mine)
    return ties


def mirrored_angle(spec: str, value: float, tie: Tie) -> float:
    """A tied joint's ``axis_theta``, ``axis_phi`` or offset from its source's (other
    specs come over unchanged). With axis ``a = (sin t cos p, sin t sin p, cos t)``, a
    mirror across y = 0 turns about ``(-ax, ay, -az)``: ``(pi - t, pi - p)``; across
    x = 0 about ``(ax, -ay, -az)``: ``(pi - t, -p)``; both: ``(-ax, -ay, az)``:
    ``(t, p + pi)``. A joint's offset rotation R becomes M R M (M the mirror): across
    y = 0 its roll and yaw change sign, across x = 0 its pitch and yaw, across both its
    roll and pitch."""
    if not (tie.flip_x or tie.flip_y):
        return value
    if spec.startswith("offset_"):  # M R M: each turn about a flipped plane's normal
        flipped = {
            "offset_roll": tie.flip_y,
            "offset_pitch": tie.flip_x,
            "offset_yaw": tie.flip_x != tie.flip_y,
        }
        return 0.0 - value if flipped[spec] else value  # no -0.0 in params
    if spec not in ("axis_theta", "axis_phi"):
        return value
    if tie.flip_x and tie.flip_y:
        return value if spec == "axis_theta" else value + math.pi
    if spec == "axis_theta":
        return math.pi - value
    return math.pi - value if tie.flip_y else -value


def unmirrored_angle(spec: str, value: float, tie: Tie) -> float:
    """The source's spec from a tied joint's (the inverse of ``mirrored_angle``): what
    an encoded design reads where the source has no joint of its own to show it."""
    if tie.flip_x and tie.flip_y and spec == "axis_phi":
        return value - math.pi
    return mirrored_angle(spec, value, tie)  # every other mirroring is its own inverse


def slot_used(key: str, members: set[str], children: set[str], ties: Mapping[str, Tie]) -> bool:
    """Whether a spec slot (``"a.length"``, ``"a.joint.choice.0"``) is used where
    ``members`` are the links and ``children`` the joints' children: by its instance,
    or by an instance tied to it there that takes the spec (not its own ``position``)."""
    instance, _, rest = key.partition(".")
    joint = rest.startswith("joint.")
    users = children if joint else members
    if instance in users:
        return True
    spec = rest.removeprefix("joint.").partition(".")[0]
    return any(
        tie.source == instance and not (joint and spec in tie.own)
        for name, tie in ties.items()
        if name in users
    )
