"""Links that interpenetrate at the rest pose: a design that cannot be built.

Both engines build a robot without collisions between its own links, so a design whose
legs lie inside its torso, or whose two arms run through each other, simulates as if
it were real and can score well (issue 60: a quadruped's best design had its legs
hidden in its body). This module finds such designs from their geometry alone, before
any simulation: pure NumPy, on the SDK's import path.

The geometry is the decoded design's collision shapes (box, cylinder, capsule: the
shapes a design's links have; a URDF template's robot, meshes and all, is not checked,
see docs/study-file.md) at the rest pose (every driven joint at 0, or the limit nearest 0:
``adclient.spawn``), all in one frame. Two links *overlap* when a point of one lies
deeper than :data:`TOLERANCE` inside the other, by the exact signed distance of the
other's shape, over points sampled through the first (its axis, rings and surface,
:data:`MAX_SAMPLES_ALONG` along it at most).

What is normal at a joint: links that meet at a joint point (a parent and its child,
or children attached at one point of their parent) always touch there, and two round
links leaving one point overlap near it whatever the angle between them. Near that
point is a ball about it whose radius is the sum of the two largest radii of the
links meeting there; only what lies outside it counts. So a child touching its
parent's end, a leg turned down off a torso's end, or arms splayed from one shoulder
are normal; a child inside its parent (its joint mid-parent, the child along the
parent's axis), siblings along one line, or a link folded back through another are
not.

Cost: for n links, n (n - 1) / 2 pairs, most dismissed by their bounding spheres; each
remaining pair evaluates at most a few hundred points against a shape. A space has at
most 32 instances, so a design is checked in milliseconds.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from adclient.design import DesignSpace
from adclient.designs import Design, Link
from adclient.spawn import design_model, link_frames, spawn_pose

TOLERANCE = 0.002
"""How deep (m) a point of one link may lie inside another before they overlap: the
sampling's resolution and a rounding's, not a physical clearance."""

MAX_SAMPLES_ALONG = 24
"""The most cross-sections sampled along a link (its length over a quarter of its
radius, at least 3)."""

RING = 8
"""Points on each ring of a cross-section (round shapes) or on each edge set (boxes)."""


@dataclass(frozen=True)
class Overlap:
    """Two links interpenetrating at the rest pose, by ``depth`` metres."""

    first: str
    second: str
    depth: float

    def __str__(self) -> str:
        return f"{self.first} and {self.second} ({self.depth * 1000:.0f} mm deep)"


@dataclass(frozen=True)
class _Shape:
    name: str
    kind: str
    centre: np.ndarray
    turn: np.ndarray
    """Columns: the shape's own axes in the common frame; its long axis is the third."""
    radius: float
    half_length: float
    bound: float
    """The radius of a ball about ``centre`` that holds the whole shape."""

    def distance(self, points: np.ndarray) -> np.ndarray:
        """Signed distance of each point (rows) to the shape's surface: negative inside."""
        local = (points - self.centre) @ self.turn
        if self.kind == "capsule":
            along = np.clip(local[:, 2], -self.half_length, self.half_length)
            nearest = np.zeros_like(local)
            nearest[:, 2] = along
            return np.linalg.norm(local - nearest, axis=1) - self.radius
        if self.kind == "box":
            half = np.array([self.radius, self.radius, self.half_length])
            excess = np.abs(local) - half
        else:  # a cylinder: its radial and axial excess
            radial = np.hypot(local[:, 0], local[:, 1]) - self.radius
            excess = np.stack([radial, np.abs(local[:, 2]) - self.half_length], axis=1)
        outside = np.linalg.norm(np.maximum(excess, 0.0), axis=1)
        return outside + np.minimum(excess.max(axis=1), 0.0)

    def samples(self) -> np.ndarray:
        """Points through the shape (rows, in the common frame): its axis, rings at half
        its radius and at its surface, and its end faces'."""
        length = 2.0 * self.half_length
        count = min(MAX_SAMPLES_ALONG, max(3, math.ceil(length / max(self.radius / 4, 1e-9))))
        along = np.linspace(-self.half_length, self.half_length, count)
        angles = np.linspace(0.0, 2.0 * math.pi, RING, endpoint=False)
        if self.kind == "box":
            # a square's edges and middles: the corners and mid-sides, and the centre
            offsets = [(x, y) for x in (-1.0, 0.0, 1.0) for y in (-1.0, 0.0, 1.0)]
            offsets += [(x / 2, y / 2) for x in (-1.0, 1.0) for y in (-1.0, 1.0)]
            section = np.array(offsets) * self.radius
        else:
            rings = [(0.0, 0.0)]
            for scale in (0.5, 1.0):
                rings += [
                    (scale * self.radius * math.cos(a), scale * self.radius * math.sin(a))
                    for a in angles
                ]
            section = np.array(rings)
        if self.kind == "capsule":  # its round ends too
            along = np.concatenate(
                [along, [-self.half_length - self.radius, self.half_length + self.radius]]
            )
        local = np.array([(x, y, z) for z in along for x, y in section])
        return self.centre + local @ self.turn.T


def _shape(link: Link, turn: np.ndarray, at: np.ndarray) -> _Shape:
    """A design link's shape, its frame at (``turn``, ``at``): it spans z in [0, length]
    of its frame (``adclient.design``); a capsule's round ends reach beyond."""
    half = link.length / 2
    centre = at + turn[:, 2] * half
    if link.shape == "capsule":
        bound = half + link.radius
    elif link.shape == "box":
        bound = math.sqrt(2 * link.radius**2 + half**2)
    else:
        bound = math.hypot(link.radius, half)
    return _Shape(link.name, link.shape, centre, turn, link.radius, half, bound)


def _meeting_points(
    design: Design, origins: dict[str, np.ndarray]
) -> list[tuple[set[str], np.ndarray]]:
    """Each joint point and the links that meet there: a parent and the children
    attached at one point of it (their joints' origins within :data:`TOLERANCE`)."""
    points: list[tuple[set[str], np.ndarray]] = []
    for joint in design.joints:
        origin = origins[joint.child]
        for names, point in points:
            if joint.parent in names and np.linalg.norm(point - origin) <= TOLERANCE:
                names.add(joint.child)
                break
        else:
            points.append(({joint.parent, joint.child}, origin))
    return points


def rest_overlaps(design: Design, *, tolerance: float = TOLERANCE) -> list[Overlap]:
    """Every pair of the design's links that interpenetrate at its rest pose, deepest
    first (see the module docstring for what is normal at a joint)."""
    model = design_model(design)
    joints = spawn_pose(model, lay_down=False, fixed_base=True).joints
    links = {link.name: link for link in design.links}
    shapes: dict[str, _Shape] = {}
    origins: dict[str, np.ndarray] = {}
    for name, turn, at in link_frames(model, np.eye(3), np.zeros(3), joints):
        shapes[name] = _shape(links[name], turn, at)
        origins[name] = at
    radii = {link.name: link.radius for link in design.links}
    balls: dict[frozenset[str], list[tuple[np.ndarray, float]]] = {}
    for names, point in _meeting_points(design, origins):
        largest = sorted((radii[name] for name in names), reverse=True)[:2]
        for first in names:
            for second in names:
                if first < second:
                    balls.setdefault(frozenset((first, second)), []).append((point, sum(largest)))
    samples = {name: shape.samples() for name, shape in shapes.items()}
    found = []
    order = [link.name for link in design.links]
    for i, first in enumerate(order):
        for second in order[i + 1 :]:
            a, b = shapes[first], shapes[second]
            if np.linalg.norm(a.centre - b.centre) > a.bound + b.bound:
                continue
            meeting = balls.get(frozenset((first, second)), [])
            depth = max(_depth(samples[first], b, meeting), _depth(samples[second], a, meeting))
            if depth > tolerance:
                found.append(Overlap(first, second, depth))
    return sorted(found, key=lambda overlap: -overlap.depth)


def _depth(points: np.ndarray, shape: _Shape, balls: Sequence[tuple[np.ndarray, float]]) -> float:
    """How deep the deepest of ``points`` lies inside ``shape``, leaving out those in
    ``balls`` (the joint points where the two links meet); 0 where none does."""
    for point, radius in balls:
        points = points[np.linalg.norm(points - point, axis=1) > radius]
    if not len(points):
        return 0.0
    return max(0.0, float(-shape.distance(points).min()))


def overlap_reason(overlaps: Iterable[Overlap], *, limit: int = 6) -> str:
    """Why a design cannot be built, naming its overlapping links (the ``limit``
    deepest pairs, and how many more)."""
    listed = list(overlaps)
    named = ", ".join(str(overlap) for overlap in listed[:limit])
    more = f" and {len(listed) - limit} more pairs" if len(listed) > limit else ""
    return f"links interpenetrate at the rest pose: {named}{more}"


SPACE_SAMPLES = 16
"""Designs of a space checked at its creation (at least one of each structure, of the
first 16 structures): each structure's middle, its lower and upper corners, then
seeded random points of its specs."""


def space_overlaps(space: DesignSpace) -> str | None:
    """Why no design of ``space`` can be built, or None: when every design checked
    (:data:`SPACE_SAMPLES`, spread over its structures) has links interpenetrating at
    the rest pose, the pairs that do in all of them (else in the first), by structure."""
    from adclient.decode import build_design, spec_layout

    layout = spec_layout(space)
    structures = range(min(len(layout.structures), SPACE_SAMPLES))
    each = max(1, SPACE_SAMPLES // len(structures))
    rng = np.random.default_rng(0)
    points = [np.full(layout.size, 0.5), np.zeros(layout.size), np.ones(layout.size)]
    points += [rng.random(layout.size) for _ in range(max(0, each - len(points)))]
    named: list[str] = []
    for structure in structures:
        common: set[frozenset[str]] | None = None
        first: list[Overlap] = []
        for x in points[:each]:
            values = dict(zip(layout.names, layout.denormalise(x).tolist(), strict=True))
            found = rest_overlaps(build_design(space, layout, structure, values))
            if not found:
                return None
            first = first or found
            pairs = {frozenset((o.first, o.second)) for o in found}
            common = pairs if common is None else common & pairs
        shown = [o for o in first if frozenset((o.first, o.second)) in (common or set())]
        where = f"structure {structure}: " if len(structures) > 1 else ""
        named.append(where + ", ".join(f"{o.first} and {o.second}" for o in (shown or first)[:6]))
    checked = len(structures) * min(each, len(points))
    return (
        f"every design's links interpenetrate at the rest pose ({checked} designs checked): "
        f"{'; '.join(named)}. Turn the joints apart (offset_roll, offset_pitch, offset_yaw) "
        "or move them (position), or set allow_overlaps: true to evaluate such designs "
        "(docs/study-file.md, Designs that can exist)"
    )
