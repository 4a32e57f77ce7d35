"""A replay (``replay.json``, :class:`adclient.schemas.Replay`) drawn as an animated GIF:
``adclient replay TRIAL --out walk.gif``.

The SDK never imports a simulator, so the frames are drawn here from the trial's URDF
and the replay alone: each link's collision shapes (boxes, cylinders, capsules, spheres)
posed by the URDF's kinematics (``adclient.spawn.link_frames``, the walk the worker's
spawn pose uses) at each frame, projected orthographically from a fixed three-quarter
view and filled as convex outlines, nearest last, over the ground line. NumPy draws the
geometry; Pillow (imported when a GIF is written, not with the SDK) the pixels.
"""

from __future__ import annotations

import io
import math
from collections.abc import Iterator

import numpy as np

from adclient.schemas.replays import Replay
from adclient.spawn import link_frames, rpy_rotation
from adclient.urdf_model import Shape, UrdfModel

AZIMUTH = math.radians(35.0)
ELEVATION = math.radians(20.0)
MIN_FRAME_MS = 20
"""The shortest frame a GIF viewer shows as asked (browsers slow shorter ones to 100 ms)."""
MAX_GIF_FRAMES = 500
"""The most frames a GIF gets: a longer replay is drawn every k-th frame."""
COLOURS = [(37, 99, 235), (234, 88, 12), (22, 163, 74), (147, 51, 234), (219, 39, 119)]
RIM = 12
"""Points around a cylinder's rim, a capsule's or sphere's circle."""


def _view() -> np.ndarray:
    """World -> view rows: screen right, screen up, towards the viewer."""
    ca, sa, ce, se = math.cos(AZIMUTH), math.sin(AZIMUTH), math.cos(ELEVATION), math.sin(ELEVATION)
    right = np.array([ca, sa, 0.0])
    towards = np.array([sa * ce, -ca * ce, se])
    up = np.cross(towards, right)
    return np.stack([right, up, towards])


def _shape_points(shape: Shape) -> np.ndarray:
    """Points on a shape's outline in its own frame (a convex hull of them is its picture)."""
    if shape.kind == "box":
        sides = np.array(shape.size[:3]) / 2
        corners = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)])
        return corners * sides
    angles = np.linspace(0.0, 2 * math.pi, RIM, endpoint=False)
    circle = np.stack([np.cos(angles), np.sin(angles), np.zeros(RIM)], axis=1)
    radius = shape.size[0]
    if shape.kind == "sphere":
        rings = [circle, circle[:, [0, 2, 1]], circle[:, [2, 0, 1]]]
        return np.concatenate(rings) * radius
    half = shape.size[1] / 2 if len(shape.size) > 1 else 0.0
    ends = [circle * radius + [0.0, 0.0, z] for z in (-half, half)]
    if shape.kind == "capsule":  # each end's ball
        ends += [
            (ring * radius) + [0.0, 0.0, z]
            for z in (-half, half)
            for ring in (circle[:, [0, 2, 1]], circle[:, [2, 0, 1]])
        ]
    return np.concatenate(ends)


def _hull(points: np.ndarray) -> np.ndarray:
    """The convex hull of 2D points, counter-clockwise (Andrew's monotone chain)."""
    ordered = sorted(set(map(tuple, np.round(points, 9).tolist())))
    if len(ordered) < 3:
        return np.array(ordered)

    def half(sequence: list[tuple[float, ...]]) -> list[tuple[float, ...]]:
        chain: list[tuple[float, ...]] = []
        for p in sequence:
            while len(chain) >= 2:
                (ax, ay), (bx, by) = chain[-2], chain[-1]
                if (bx - ax) * (p[1] - ay) - (by - ay) * (p[0] - ax) > 0:
                    break
                chain.pop()
            chain.append(p)
        return chain

    lower, upper = half(ordered), half(ordered[::-1])
    return np.array(lower[:-1] + upper[:-1])


def frame_shapes(model: UrdfModel, replay: Replay, k: int) -> Iterator[tuple[int, np.ndarray]]:
    """Each shape of the robot at frame ``k``: its link's number and its points in world."""
    x, y, z, w = replay.orientation(k)
    turn = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
    names = list(model.links)
    frames = link_frames(model, turn, np.array(replay.position(k)), replay.joint_positions(k))
    for name, rotation, origin in frames:
        for shape in model.links[name].shapes:
            local = rotation @ rpy_rotation(shape.origin.rpy)
            at = origin + rotation @ np.array(shape.origin.xyz)
            yield names.index(name), _shape_points(shape) @ local.T + at


def render_frames(
    model: UrdfModel, replay: Replay, *, width: int = 480, height: int = 360, step: int = 1
) -> list[np.ndarray]:
    """Every ``step``-th frame of the replay (and its last) as an RGB array, all drawn at
    one scale that holds the whole episode."""
    from PIL import Image, ImageDraw

    view = _view()
    chosen = list(range(0, len(replay.frames), step))
    if chosen[-1] != len(replay.frames) - 1:
        chosen.append(len(replay.frames) - 1)
    posed = [
        [(link, points @ view.T) for link, points in frame_shapes(model, replay, k)] for k in chosen
    ]
    ground = np.array([[0.0, 0.0, 0.0]]) @ view.T
    every = [points for shapes in posed for _, points in shapes] or [ground]
    both = np.concatenate(every)
    low, high = both[:, :2].min(axis=0), both[:, :2].max(axis=0)
    low[1] = min(low[1], float((np.zeros(3) @ view.T)[1]))
    span = np.maximum(high - low, 1e-3)
    scale = 0.85 * min(width / span[0], height / span[1])
    middle = (low + high) / 2

    def pixel(points: np.ndarray) -> list[tuple[float, float]]:
        xy = (points[:, :2] - middle) * scale
        return [(width / 2 + px, height / 2 - py) for px, py in xy.tolist()]

    images = []
    for shapes, k in zip(posed, chosen, strict=True):
        image = Image.new("RGB", (width, height), (249, 250, 251))
        draw = ImageDraw.Draw(image)
        # the ground plane z = 0 under the robot: a grid of lines in world x and y
        x0, y0 = replay.position(k)[:2]
        for offset in np.linspace(-1.0, 1.0, 9):
            for line in (
                [[x0 + offset, y0 - 1.0, 0.0], [x0 + offset, y0 + 1.0, 0.0]],
                [[x0 - 1.0, y0 + offset, 0.0], [x0 + 1.0, y0 + offset, 0.0]],
            ):
                draw.line(pixel(np.array(line) @ view.T), fill=(209, 213, 219), width=1)
        for link, points in sorted(shapes, key=lambda item: float(item[1][:, 2].mean())):
            colour = COLOURS[link % len(COLOURS)]
            outline = pixel(_hull(points[:, :2]) if len(points) > 2 else points)
            draw.polygon(outline, fill=colour, outline=(17, 24, 39))
        seconds = k * replay.frame_period
        draw.text((8, 8), f"t = {seconds:.2f} s", fill=(17, 24, 39))
        images.append(np.asarray(image))
    return images


def replay_gif(model: UrdfModel, replay: Replay, *, speed: float = 1.0) -> bytes:
    """The replay as an animated GIF that loops, played at ``speed`` times real time
    (frames dropped where one would last under ``MIN_FRAME_MS``)."""
    from PIL import Image

    if speed <= 0:
        raise ValueError("speed must be positive")
    period_ms = replay.frame_period * 1000 / speed
    step = max(
        1, math.ceil(MIN_FRAME_MS / period_ms), math.ceil(len(replay.frames) / MAX_GIF_FRAMES)
    )
    images = [Image.fromarray(rgb) for rgb in render_frames(model, replay, step=step)]
    buffer = io.BytesIO()
    images[0].save(
        buffer,
        format="GIF",
        save_all=True,
        append_images=images[1:],
        duration=max(MIN_FRAME_MS, round(period_ms * step)),
        loop=0,
        optimize=True,
    )
    return buffer.getvalue()
