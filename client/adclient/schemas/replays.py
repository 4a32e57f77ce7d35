"""A trial's evaluation episode, replayable: the ``replay.json`` artifact a worker uploads,
one contract for the worker that writes it, the dashboard's 3D view that plays it and
``adclient replay`` that draws it as a GIF.

Each frame is the root link's URDF frame in the world (position, then orientation as a
quaternion x, y, z, w) followed by the driven joints' positions in ``joints`` order: the
pose the simulator had after each control step (frame 0: after the episode's reset), so
the URDF posed at a frame is the simulator's robot then. Numbers are rounded to
``DECIMALS`` places (0.1 mm, 0.1 mrad): JSON of about 7 characters a number, twice a
float32 file's size, but read by the dashboard's ``fetch().json()`` and this model with
no decoder of its own, and compressed by any HTTP or archive gzip to about float32's.

Its size is bounded: at most ``MAX_FRAMES`` frames (a longer episode keeps every
``every``-th control step, and its last), so at most ``MAX_FRAMES * (7 + joints)``
numbers whatever ``episode_steps`` (up to 100,000) a study sets.
"""

from __future__ import annotations

from pydantic import BaseModel, Field, model_validator

REPLAY_ARTIFACT = "replay.json"
"""The artifact name a worker uploads the replay as."""

MAX_FRAMES = 1001
"""The most frames a replay holds: the reset pose and 1,000 steps."""

DECIMALS = 4
"""Decimal places every number of a frame is rounded to."""

BASE_SIZE = 7
"""A frame's leading numbers: the root frame's position (3) and quaternion xyzw (4)."""


class Replay(BaseModel):
    """``replay.json``: one evaluation episode, a frame per recorded control step."""

    trial_id: int | None = None
    seed: int | None = Field(default=None, description="the evaluation episode's seed")
    control_period: float = Field(gt=0, description="simulated seconds per control step")
    every: int = Field(default=1, ge=1, description="control steps from one frame to the next")
    joints: list[str] = Field(description="the driven joints, in each frame's order")
    frames: list[list[float]] = Field(
        max_length=MAX_FRAMES,
        description="per frame: root position xyz, quaternion xyzw, then the joints",
    )

    @model_validator(mode="after")
    def _frame_sizes(self) -> Replay:
        size = BASE_SIZE + len(self.joints)
        for k, frame in enumerate(self.frames):
            if len(frame) != size:
                raise ValueError(f"frame {k} has {len(frame)} numbers, expected {size}")
        return self

    @property
    def frame_period(self) -> float:
        """Simulated seconds from one frame to the next."""
        return self.control_period * self.every

    def position(self, k: int) -> tuple[float, float, float]:
        x, y, z = self.frames[k][0:3]
        return (x, y, z)

    def orientation(self, k: int) -> tuple[float, float, float, float]:
        x, y, z, w = self.frames[k][3:7]
        return (x, y, z, w)

    def joint_positions(self, k: int) -> dict[str, float]:
        return dict(zip(self.joints, self.frames[k][BASE_SIZE:], strict=True))

    def to_json(self) -> bytes:
        """The artifact's bytes, compact."""
        return self.model_dump_json(exclude_none=True).encode()
