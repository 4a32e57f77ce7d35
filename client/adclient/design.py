"""The design-space model: parts, joints, instances and candidate tree structures.

A *design space* says which parts a robot is made of, how they may be connected
(candidate tree structures) and which specifications are searched (given as a
``{low, high}`` bound) or fixed (given as a number). A *design* is one point of it:
a tree plus concrete specs, ready to be written as URDF.

Geometry conventions (shared by decoding, the URDF writer and the worker tasks):
- Every link frame sits at the joint to its parent. A cylinder link extends along
  the frame's +z axis from 0 to ``length``.
- A child's joint sits on its parent's axis at ``position * parent.length``
  (``position`` = 1.0: at the parent's far end); at joint angle 0 the child's frame
  is aligned with its parent's, so a chain at rest is straight along +z.
- A revolute joint's axis, in that frame, is
  ``(sin(theta) cos(phi), sin(theta) sin(phi), cos(theta))``: theta = 0 runs along
  the links, theta = pi/2 is perpendicular to them.
- The spec vector orders the instances' part specs, then the instances' joint specs:
  the joint of an instance is the one to its parent, so every structure has the same
  spec slots; the root's joint slots are padded.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

NAME_PATTERN = r"^[A-Za-z][A-Za-z0-9_\-]{0,63}$"


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class Bound(_Strict):
    """A searched spec: any value in [low, high]."""

    low: float
    high: float


SpecValue = float | Bound
"""A spec is fixed (a number) or searched (a Bound)."""


class PartType(_Strict):
    shape: Literal["cylinder", "box"] = "cylinder"
    length: SpecValue = 0.4
    radius: SpecValue = 0.04
    mass: SpecValue = 1.0


class JointType(_Strict):
    type: Literal["revolute"] = "revolute"
    axis_theta: SpecValue = Bound(low=0.0, high=3.141592653589793)
    axis_phi: SpecValue = Bound(low=0.0, high=3.141592653589793)
    position: SpecValue = 1.0
    lower: SpecValue = -1.5707963267948966
    upper: SpecValue = 1.5707963267948966
    effort: SpecValue = 20.0
    velocity: SpecValue = 5.0


class PartInstance(_Strict):
    name: str = Field(pattern=NAME_PATTERN)
    part: str
    overrides: dict[str, SpecValue] = Field(default_factory=dict)
    joint_overrides: dict[str, SpecValue] = Field(default_factory=dict)


Edge = tuple[str, str]
"""(parent instance, child instance): one revolute joint."""


class DesignSpace(_Strict):
    type: Literal["design"] = "design"
    parts: dict[str, PartType]
    joint: JointType = Field(default_factory=JointType)
    instances: list[PartInstance] = Field(min_length=1, max_length=32)
    structures: list[list[Edge]] | Literal["all"] = Field(
        description="Candidate trees as edge lists, or 'all' trees over the instances"
    )
    max_structures: int = Field(default=64, ge=1, le=1000)
    fusion_solver: Literal["osqp", "exact"] = "osqp"
    fusion_margin: float = Field(default=0.0, ge=0.0)
    reference_per_structure: int = Field(default=16, ge=2, le=256)


class Link(BaseModel):
    name: str
    shape: Literal["cylinder", "box"]
    length: float
    radius: float
    mass: float


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


class Design(BaseModel):
    """One concrete robot: a tree of links joined by revolute joints."""

    structure_index: int
    root: str
    links: list[Link]
    joints: list[Joint]


class Representation(BaseModel):
    """What turns a search vector back into a design, computed once per study.

    ``identity``: one structure; the vector is the spec vector normalised to [0, 1].
    ``fused``: several structures; the vector lives in the MDS embedding of the
    fused distances, decoded by nearest reference design plus an affine map.
    """

    kind: Literal["identity", "fused"]
    spec_names: list[str]
    spec_low: list[float]
    spec_high: list[float]
    structures: list[list[Edge]]
    bounds: list[list[float]] = Field(description="search box, [lows, highs]")
    ref_coords: list[list[float]] = Field(default_factory=list)
    ref_structure: list[int] = Field(default_factory=list)
    affine: list[list[list[float]]] = Field(default_factory=list)
    info: dict[str, float | int | str] = Field(default_factory=dict)
