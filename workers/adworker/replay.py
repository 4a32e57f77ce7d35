"""Recording an evaluation episode as a :class:`adclient.schemas.Replay` (``replay.json``).

:class:`ReplayRecorder` stands in for the env while the evaluation episodes run: it
passes every call through and keeps, for the episode under way, the root's pose and the
joints' positions after its reset and after each control step. An engine reports the
root's pose in its pose frame (its centre of mass: ``Snapshot.poses``), which is the
URDF's root frame moved by a constant offset; the offset is read from the episode's
first snapshot, where the root frame is where the robot was placed (``robot.spawn``),
so the replay holds the URDF's own root frame whatever the engine.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from adclient.schemas.replays import BASE_SIZE, DECIMALS, MAX_FRAMES, Replay
from adworker.tasks.snapshot import POSE_ORIENTATION, POSE_POSITION


def rotation_matrices(q: np.ndarray) -> np.ndarray:
    """Rotation matrices of quaternions ``q`` (..., 4) in x, y, z, w order."""
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def quaternion_products(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Quaternion products a * b (xyzw), broadcast."""
    ax, ay, az, aw = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bx, by, bz, bw = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    return np.stack(
        [
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz,
        ],
        -1,
    )


def _conjugate(q: np.ndarray) -> np.ndarray:
    return q * np.array([-1.0, -1.0, -1.0, 1.0])


def root_frames(
    positions: np.ndarray,
    orientations: np.ndarray,
    placed: tuple[tuple[float, ...], tuple[float, ...]],
) -> tuple[np.ndarray, np.ndarray]:
    """The root's URDF frame at each pose-frame pose (n, 3) and (n, 4), given that the
    first is the robot as ``placed`` (its root frame's position and xyzw quaternion)."""
    spawn_at = np.array(placed[0], dtype=float)
    spawn_turn = np.array(placed[1], dtype=float)
    spawn_turn = spawn_turn / np.linalg.norm(spawn_turn)
    # pose frame = root frame * offset, so root frame = pose frame * offset^-1
    offset_turn = quaternion_products(_conjugate(spawn_turn), orientations[0])
    offset_at = rotation_matrices(_conjugate(spawn_turn)) @ (positions[0] - spawn_at)
    turns = quaternion_products(orientations, _conjugate(offset_turn))
    ats = positions - np.einsum("nij,j->ni", rotation_matrices(turns), offset_at)
    # one hemisphere, so a player interpolating frames never swings the long way round
    turns = np.where(turns[:, 3:4] < 0, -turns, turns)
    return ats, turns


class ReplayRecorder:
    """The env, recording: pass it where the env goes (``evaluate_policy``), then ask
    :meth:`replay` for the last episode it saw."""

    def __init__(self, env: Any) -> None:
        self._env = env
        self._positions: list[Any] = []
        self._orientations: list[Any] = []
        self._joints: list[list[float]] = []
        self.seed: int | None = None

    def __getattr__(self, name: str) -> Any:
        return getattr(self._env, name)

    def _keep(self) -> None:
        snapshot = self._env.snapshot()
        root = snapshot.poses[0]
        self._positions.append(root[POSE_POSITION])
        self._orientations.append(root[POSE_ORIENTATION])
        self._joints.append(list(snapshot.q))

    def reset(self, *args: Any, **kwargs: Any) -> Any:
        answer = self._env.reset(*args, **kwargs)
        self.seed = kwargs.get("seed")
        self._positions, self._orientations, self._joints = [], [], []
        self._keep()
        return answer

    def step(self, action: Any) -> Any:
        answer = self._env.step(action)
        self._keep()
        return answer

    def replay(self, *, trial_id: int | None = None) -> Replay | None:
        """The last episode recorded (None before any), at most ``MAX_FRAMES`` frames."""
        if not self._joints:
            return None
        steps = len(self._joints) - 1
        every = max(1, math.ceil(steps / (MAX_FRAMES - 1)))
        kept = list(range(0, steps + 1, every))
        if kept[-1] != steps:  # the last pose, the one the task scored, always
            kept[-1] = steps
        robot = self._env.robot
        spawn = robot.spawn
        ats, turns = root_frames(
            np.array(self._positions, dtype=float)[kept],
            np.array(self._orientations, dtype=float)[kept],
            (tuple(spawn.position), tuple(spawn.orientation)),
        )
        joints = np.array(self._joints, dtype=float).reshape(len(self._joints), -1)[kept]
        frames = np.round(np.concatenate([ats, turns, joints], axis=1), DECIMALS)
        assert frames.shape[1] == BASE_SIZE + len(robot.joints)
        return Replay(
            trial_id=trial_id,
            seed=self.seed,
            control_period=float(self._env.sim.control_period),
            every=every,
            joints=[joint.name for joint in robot.joints],
            frames=frames.tolist(),
        )
