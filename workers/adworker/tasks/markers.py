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


def draw_markers(rgb: np.ndarray, camera: Camera, markers: Sequence[Marker]) -> np.ndarray:
    """``rgb`` (a picture ``camera`` took) with each marker drawn where the camera sees
    its point: a dot of its colour with a dark rim, its label to the right."""
    if not markers:
        return rgb
    from PIL import Image, ImageDraw

    image = Image.fromarray(rgb)
    draw = ImageDraw.Draw(image)
    for marker in markers:
        pixel = camera.pixel(marker.position)
        if pixel is None:
            continue
        u, v = pixel
        box = (u - DOT_RADIUS, v - DOT_RADIUS, u + DOT_RADIUS, v + DOT_RADIUS)
        draw.ellipse(box, fill=marker.rgb(), outline=RIM, width=1)
        if marker.label:
            draw.text((u + DOT_RADIUS + 3, v - DOT_RADIUS - 1), marker.label, fill=RIM)
    return np.asarray(image, dtype=np.uint8).copy()
