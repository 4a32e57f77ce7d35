"""A design: one robot of a design space, decoded (links, joints, its tree), and the
representation that maps search vectors to designs (``adclient.decode``)."""

from __future__ import annotations

import math
from typing import Any, Literal

from pydantic import (
    BaseModel,
    Field,
    SerializerFunctionWrapHandler,
    model_serializer,
)

from adclient.specs import OFFSET_SPECS, Shape, drop_unset
from adclient.trees import Edge
from adclient.urdf_model import JointKind


class Link(BaseModel):
    """One link of a design. ``mass`` is what it weighs (kg), whatever gave it: its
    ``mass`` spec, or ``density`` (kg/m^3, then also set) times its volume
    (``link_mass``); the URDF writer and the simulator use ``mass``."""

    name: str
    shape: Shape
    length: float
    radius: float
    mass: float
    density: float | None = None
    choice: str | None = None
    """The catalogue component it is, when its part chooses one."""

    @model_serializer(mode="wrap")
    def _density_when_set(self, handler: SerializerFunctionWrapHandler) -> dict[str, Any]:
        data: dict[str, Any] = handler(self)
        drop_unset(data, "density", "choice")
        return data


class Joint(BaseModel):
    name: str
    parent: str
    child: str
    axis: tuple[float, float, float]
    axis_theta: float
    axis_phi: float
    position: float
    lower: float
    upper: float
    effort: float
    velocity: float
    choice: str | None = None
    """The catalogue component it is, when the joint chooses one."""
    kind: JointKind = "revolute"
    offset_roll: float | None = None
    offset_pitch: float | None = None
    offset_yaw: float | None = None
    """How its frame is turned on its parent (``OFFSET_SPECS``); None: its space turns
    no joint."""

    @property
    def offset(self) -> tuple[float, float, float]:
        """(roll, pitch, yaw), 0 where not set."""
        return (self.offset_roll or 0.0, self.offset_pitch or 0.0, self.offset_yaw or 0.0)

    @property
    def limits(self) -> tuple[float, float]:
        """(lower, upper) as a simulator drives it: a revolute or continuous joint with
        an empty range (lower = upper) turns all round, -pi to pi."""
        if self.kind in ("revolute", "continuous") and not self.lower < self.upper:
            return -math.pi, math.pi
        return self.lower, self.upper

    @model_serializer(mode="wrap")
    def _set_fields_only(self, handler: SerializerFunctionWrapHandler) -> dict[str, Any]:
        """``choice`` only when set, ``kind`` only when not revolute: a design's JSON is
        what it was before them."""
        data: dict[str, Any] = handler(self)
        drop_unset(data, "choice", *OFFSET_SPECS)
        if data.get("kind") == "revolute":
            del data["kind"]
        return data


class Design(BaseModel):
    """One concrete robot: a tree of links joined by revolute joints."""

    structure_index: int
    root: str
    links: list[Link]
    joints: list[Joint]

    def edges(self) -> list[Edge]:
        return [(joint.parent, joint.child) for joint in self.joints]


class Representation(BaseModel):
    """What turns a search vector back into a design, computed once per study.

    ``identity``: one structure; the vector is the spec vector normalised to [0, 1].
    ``fused``: several structures; the vector lives in the MDS embedding of the
    fused distances, decoded by nearest reference design plus an affine map.
    ``onehot``: several structures, plain encoding: one [0, 1] coordinate per
    structure (the largest wins, ties to the first), then the normalised spec vector.
    ``mixed``: several structures; the vector is the structure index (searched in
    [-0.5, S - 0.5] and rounded, so every structure owns an equal share) followed by
    the normalised spec vector, decoded by identity. ``structure_coords`` (S x k)
    places the structures in the fused geometry (the proposer's structure kernel).

    ``affine[s]`` is a ``(dim + 1) x p`` matrix: the normalised spec vector of
    structure ``s`` at search vector ``v`` is ``[v, 1] @ affine[s]``, clipped to
    [0, 1]. ``ref_coords`` (M x dim) and ``ref_structure`` (M) are the reference
    designs' coordinates and structure indices.

    ``spec_low``/``spec_high`` are the free specs' physical ranges, for reading; the
    decoder takes each slot's scale (linear, or ``log``) from the space's Bounds, which
    it always has (``adclient.decode.spec_layout``), so a representation's JSON is the
    same for log and linear specs.
    """

    kind: Literal["identity", "mixed", "fused", "onehot"]
    spec_names: list[str]
    spec_low: list[float]
    spec_high: list[float]
    structures: list[list[Edge]]
    bounds: list[list[float]] = Field(description="search box, [lows, highs]")
    ref_coords: list[list[float]] = Field(default_factory=list)
    ref_structure: list[int] = Field(default_factory=list)
    affine: list[list[list[float]]] = Field(default_factory=list)
    structure_coords: list[list[float]] = Field(default_factory=list)
    info: dict[str, float | int | str] = Field(default_factory=dict)
