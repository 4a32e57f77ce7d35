"""Points a task marks in the trial's picture (``robot.png``): a target, a tip.

A task's ``markers(snapshot)`` hook returns :class:`Marker` s: world points, each with a
colour and an optional label. The picture frames the robot and the marked points
together, and each point is drawn over the rendered scene as a dot of its colour with a
dark rim (PyBullet's debug items do not show in ``getCameraImage``'s software renderer,
and a body added for the picture would change the world): a marker is never hidden
behind the robot. A point behind the camera is not drawn.

What a task returns is checked by a whitelist before anything is drawn
(:func:`checked_markers`): at most :data:`MAX_MARKERS` markers, finite positions within
:data:`MAX_COORDINATE` m of the origin, colours in [0, 1], labels of printable ASCII; a
marker that is not one fails the job with a message naming it.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from adworker.tasks.engine import Camera

MAX_MARKERS = 16
MAX_COORDINATE = 1000.0
"""Metres from the origin; a point farther off is a bug, not a target."""
LABEL_PATTERN = re.compile(r"[ -~]{0,32}")
"""A label: at most 32 printable ASCII characters (what the picture's font has)."""
DOT_RADIUS = 5
"""Pixels."""
RIM = (25, 25, 25)
"""The dot's rim and the label's colour: dark on the light ground and sky."""


@dataclass(frozen=True)
class Marker:
    """A world point drawn into the trial's picture."""

    position: tuple[float, float, float]
    """World coordinates, m."""
    colour: tuple[float, float, float] = (0.9, 0.1, 0.1)
    """Red, green and blue in [0, 1]."""
    label: str = ""
    """Written beside the dot (at most 32 printable ASCII characters); none when empty."""

    def rgb(self) -> tuple[int, int, int]:
        """The colour as 8-bit values, as the picture has it."""
        red, green, blue = (round(255 * value) for value in self.colour)
        return red, green, blue


def checked_markers(markers: object) -> list[Marker]:
    """``markers`` as a task returned them, each checked; ValueError naming the first
    that is not a marker the picture can show."""
    if not isinstance(markers, Sequence) or isinstance(markers, str | bytes):
        raise ValueError(f"a task's markers are a list of Marker, got {type(markers).__name__}")
    if len(markers) > MAX_MARKERS:
        raise ValueError(f"a task marks at most {MAX_MARKERS} points, got {len(markers)}")
    return [_checked(marker, f"marker {index}") for index, marker in enumerate(markers)]


def _checked(marker: object, where: str) -> Marker:
    if not isinstance(marker, Marker):
        raise ValueError(f"{where}: a Marker, got {type(marker).__name__}")
    position = _numbers(marker.position, f"{where}.position")
    if any(abs(value) > MAX_COORDINATE for value in position):
        raise ValueError(
            f"{where}.position: {position} is more than {MAX_COORDINATE:g} m from the origin"
        )
    colour = _numbers(marker.colour, f"{where}.colour")
    if any(not 0.0 <= value <= 1.0 for value in colour):
        raise ValueError(f"{where}.colour: red, green and blue in [0, 1], got {colour}")
    label = marker.label
    if not isinstance(label, str) or LABEL_PATTERN.fullmatch(label) is None:
        raise ValueError(
            f"{where}.label: at most 32 printable ASCII characters, got {str(label)[:40]!r}"
        )
    return Marker(position, colour, label)


def _numbers(value: object, where: str) -> tuple[float, float, float]:
    """Three finite numbers (bools are not numbers here)."""
    if not isinstance(value, Sequence) or isinstance(value, str | bytes) or len(value) != 3:
        raise ValueError(f"{where}: three numbers, got {str(value)[:40]!r}")
    numbers = []
    for item in value:
        if isinstance(item, bool) or not isinstance(item, int | float | np.number):
            raise ValueError(f"{where}: three numbers, got {str(value)[:40]!r}")
        number = float(item)
        if not math.isfinite(number):
            raise ValueError(f"{where}: numbers must be finite, got {number}")
        numbers.append(number)
    return numbers[0], numbers[1], numbers[2]


Box = tuple[int, int, int, int]
"""A pixel rectangle: left, top, right, bottom."""
LABEL_GAP = 3
"""Pixels between a dot's rim and its label."""


def draw_markers(rgb: np.ndarray, camera: Camera, markers: Sequence[Marker]) -> np.ndarray:
    """``rgb`` (a picture ``camera`` took) with each marker drawn where the camera sees
    its point: a dot of its colour with a dark rim, its label beside it where it
    overlaps no other label or dot (:func:`label_places`)."""
    if not markers:
        return rgb
    from PIL import Image, ImageDraw

    image = Image.fromarray(rgb)
    draw = ImageDraw.Draw(image)
    seen = []
    for marker in markers:
        pixel = camera.pixel(marker.position)
        if pixel is not None:
            seen.append((marker, (round(pixel[0]), round(pixel[1]))))
    dots = [(u - DOT_RADIUS, v - DOT_RADIUS, u + DOT_RADIUS, v + DOT_RADIUS) for _, (u, v) in seen]
    for (marker, _), dot in zip(seen, dots, strict=True):
        draw.ellipse(dot, fill=marker.rgb(), outline=RIM, width=1)
    sizes: list[tuple[int, int] | None] = []
    for marker, _ in seen:
        left, top, right, bottom = draw.textbbox((0, 0), marker.label)
        sizes.append((round(right - left), round(bottom - top)) if marker.label else None)
    for (marker, _), box in zip(seen, label_places(dots, sizes, image.size), strict=True):
        if box is not None:
            draw.text((box[0], box[1]), marker.label, fill=RIM)
    return np.asarray(image, dtype=np.uint8).copy()


def label_places(
    dots: Sequence[Box], sizes: Sequence[tuple[int, int] | None], image_size: tuple[int, int]
) -> list[Box | None]:
    """Where each dot's label goes (``None`` for a dot without one): the first of right,
    left, above and below the dot, then the same farther out (each moved inside the
    picture where it fits), whose box lies inside the picture and overlaps no dot and no
    label placed before it; if none does, the least
    overlapped of them. Labels are placed in the markers' order, so a task's first
    markers keep the places nearest their dots."""
    width, height = image_size
    placed: list[Box] = []
    places: list[Box | None] = []
    for dot, size in zip(dots, sizes, strict=True):
        if size is None:
            places.append(None)
            continue
        candidates = _candidates(dot, size, image_size)
        others = [other for other in dots if other != dot] + placed

        costs = [_placement_cost(box, others, width, height) for box in candidates]
        best = candidates[costs.index(min(costs))]
        placed.append(best)
        places.append(best)
    return places


def _placement_cost(box: Box, others: Sequence[Box], width: int, height: int) -> tuple[int, int]:
    """Whether ``box`` leaves the picture, then the pixels it shares with ``others``."""
    outside = int(box[0] < 0 or box[1] < 0 or box[2] > width or box[3] > height)
    return outside, sum(_overlap(box, other) for other in others)


def _candidates(dot: Box, size: tuple[int, int], image_size: tuple[int, int]) -> list[Box]:
    """Boxes of ``size`` around ``dot``, nearest first, each shifted into the picture
    where it fits there (a label by the picture's edge moves along it)."""
    left, top, right, bottom = dot
    label_width, label_height = size
    middle = (top + bottom) // 2 - label_height // 2
    centre = (left + right) // 2 - label_width // 2
    boxes = []
    for ring in range(4):
        reach = LABEL_GAP + ring * (label_height + LABEL_GAP)
        for x, y in (
            (right + reach, middle),
            (left - reach - label_width, middle),
            (centre, top - reach - label_height),
            (centre, bottom + reach),
        ):
            x = min(max(x, 0), max(image_size[0] - label_width, 0))
            y = min(max(y, 0), max(image_size[1] - label_height, 0))
            boxes.append((x, y, x + label_width, y + label_height))
    return list(dict.fromkeys(boxes))


def _overlap(a: Box, b: Box) -> int:
    """The pixels two boxes share."""
    width = min(a[2], b[2]) - max(a[0], b[0])
    height = min(a[3], b[3]) - max(a[1], b[1])
    return max(width, 0) * max(height, 0)
