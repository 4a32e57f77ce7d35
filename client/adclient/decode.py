"""Search vector <-> design, per docs/method.md, "Representations" (pure numpy: runs in
workers too).

The *spec vector* x holds the free specs of a space (``spec_layout``), each
normalised to [0, 1] by its bounds (a ``log`` spec on the log scale: value =
exp(ln low + x (ln high - ln low)), so whatever searches x uniformly searches such a
spec log-uniformly); slots a structure does not use (absent
instances, the root's joint) hold ``PAD``. An ``identity`` representation searches x
itself; a ``mixed`` one (the default for several structures) searches a structure
index followed by x, and decodes both by identity (the index is rounded); a
``fused`` one (the preprint's) searches the MDS embedding of the fused distances and maps
back through the nearest reference design (structure) and that structure's affine
map (specs); a ``onehot`` one (the plain encoding, ``encoding: onehot``) searches one
coordinate per structure followed by x, and decodes the largest coordinate's
structure with x's specs.
"""

from __future__ import annotations

import math
import weakref
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from adclient.catalogues import catalogue_totals, choice_slots, nearest
from adclient.design import DesignSpace
from adclient.designs import Design, Joint, Link, Representation
from adclient.specs import (
    JOINT_SPECS,
    OFFSET_SPECS,
    PART_SPECS,
    UNUSED_JOINT_SPECS,
    Bound,
    link_mass,
)
from adclient.ties import Tie, mirrored_angle, slot_used
from adclient.trees import Edge

PAD = 0.5
"""Normalised value of the spec slots a structure does not use."""
NORMALISE_ULPS = 8
"""How many neighbouring floats on each side ``SpecLayout.normalise`` tries for a slot
that decodes to the very value it was given."""


@dataclass(frozen=True)
class SpecLayout:
    """The free specs of a space: ``names[k]`` is searched in ``[low[k], high[k]]``,
    on a log scale where ``log[k]``.

    ``fixed`` holds every fixed spec (key -> value) of every instance, so a design
    can be completed from the free values. ``structures`` are the candidate trees.
    ``low`` and ``high`` are physical values; ``normalise`` and ``denormalise`` go
    between them and the [0, 1] slots of the spec vector.
    """

    names: list[str]
    low: np.ndarray
    high: np.ndarray
    fixed: dict[str, float]
    structures: list[list[Edge]]
    log: np.ndarray
    """Boolean mask of the slots searched on a log scale (``Bound.log``)."""
    ties: dict[str, Tie] = field(default_factory=dict)
    """The tied instances (``same_as``), whose free specs are their sources' slots."""
    chooses: dict[str, str] = field(default_factory=dict)
    placeholders: frozenset[str] = frozenset()
    """Joint specs their joint's kind has no use for (``UNUSED_JOINT_SPECS``): fixed
    placeholders, whatever a chosen component says."""
    """Which catalogue each choosing part (owner ``"b"``) or joint (``"b.joint"``) is
    one of (``adclient.catalogues``)."""
    catalogues: dict[str, dict[str, dict[str, float]]] = field(default_factory=dict)

    @property
    def size(self) -> int:
        return len(self.names)

    def used_slots(self, structure: Sequence[Edge]) -> np.ndarray:
        """Boolean mask of the slots a structure uses (its links, its non-root joints)."""
        return used_slots(self.names, structure, self.ties)

    def value(self, key: str, free: Mapping[str, float]) -> float:
        """A spec's value in a design whose free specs are ``free``: its own slot's, the
        chosen component's entry (a catalogue sets it), a fixed spec's, or a tied
        instance's source slot (a joint axis mirrored)."""
        if key in free:
            return float(free[key])
        owner, entry = spec_owner(key)
        if key in self.placeholders:  # its joint's kind has no use for it
            return self.fixed[key]
        if owner in self.chooses and entry in self.catalogue_of(owner)[self.first_component(owner)]:
            return float(self.catalogue_of(owner)[self.choice(owner, free)][entry])
        if key in self.fixed:
            return self.fixed[key]
        instance, _, rest = key.partition(".")
        tie = self.ties.get(instance)
        if tie is None:
            raise KeyError(key)
        value = float(free[f"{tie.source}.{rest}"])
        return mirrored_angle(rest.removeprefix("joint."), value, tie)

    def catalogue_of(self, owner: str) -> dict[str, dict[str, float]]:
        return self.catalogues[self.chooses[owner]]

    def first_component(self, owner: str) -> str:
        return next(iter(self.catalogue_of(owner)))

    def choice(self, owner: str, free: Mapping[str, float]) -> str:
        """The component a choosing part or joint is: the one nearest its searched
        entries' values (a tied instance's are its source's)."""
        catalogue = self.catalogue_of(owner)
        point = {
            slot.key: self.value(f"{owner}.choice.{slot.key}", free)
            for slot in choice_slots(catalogue)
        }
        return nearest(catalogue, point)

    def _scaled(self, values: np.ndarray) -> np.ndarray:
        """Values on each slot's own scale: their natural log where ``log``."""
        values = np.asarray(values, dtype=np.float64)
        if not self.log.any():
            return values
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(self.log, np.log(np.where(self.log, values, 1.0)), values)

    def normalise(self, values: np.ndarray) -> np.ndarray:
        """Physical values (in range) -> [0, 1] slots; a value that ``denormalise`` gave
        comes back to a slot that gives it again, to the last bit where one does (a
        log slot's exp and ln round, so the first answer may be an ulp off)."""
        values = np.asarray(values, dtype=np.float64)
        low, high = self._scaled(self.low), self._scaled(self.high)
        x = np.clip((self._scaled(values) - low) / (high - low), 0.0, 1.0)
        error = np.abs(self.denormalise(x) - values)
        for direction in (-np.inf, np.inf):  # the nearest few slots on either side
            near = x
            for _ in range(NORMALISE_ULPS):
                if not error.any():
                    return x
                near = np.clip(np.nextafter(near, direction), 0.0, 1.0)
                near_error = np.abs(self.denormalise(near) - values)
                better = near_error < error
                x, error = np.where(better, near, x), np.where(better, near_error, error)
        return x

    def denormalise(self, x: np.ndarray) -> np.ndarray:
        """[0, 1] slots -> physical values; a log slot's are within [low, high], its
        ends exactly ``low`` and ``high`` (exp(ln low) may round away from low)."""
        x = np.asarray(x, dtype=np.float64)
        if not self.log.any():
            return self.low + x * (self.high - self.low)
        low, high = self._scaled(self.low), self._scaled(self.high)
        scaled = low + x * (high - low)
        values = np.clip(np.exp(np.where(self.log, scaled, 0.0)), self.low, self.high)
        values = np.where(x <= 0.0, self.low, np.where(x >= 1.0, self.high, values))
        return np.where(self.log, values, scaled)


def spec_owner(key: str) -> tuple[str, str]:
    """(owner, spec) of a spec key: ``("b", "length")``, ``("b.joint", "effort")``."""
    instance, _, rest = key.partition(".")
    if rest.startswith("joint."):
        return f"{instance}.joint", rest.removeprefix("joint.")
    return instance, rest


def used_slots(
    names: Sequence[str], structure: Sequence[Edge], ties: Mapping[str, Tie] | None = None
) -> np.ndarray:
    """Boolean mask of the spec slots ``names`` a structure uses (its links, its
    non-root joints; a tied instance's are its source's: ``slot_used``)."""
    members = {name for edge in structure for name in edge}
    children = {child for _, child in structure}
    return np.array([slot_used(key, members, children, ties or {}) for key in names], dtype=bool)


_LAYOUTS: dict[int, SpecLayout] = {}
"""Each live space's layout, by ``id`` (dropped when the space is collected)."""


def spec_layout(space: DesignSpace) -> SpecLayout:
    """The layout of ``space``, computed once per space object: a validated space is
    not changed afterwards (its trees are kept the same way), and a server decodes and
    encodes every trial of a study through the study's one space several times. The
    layout's arrays are read-only, being shared. Kept outside the model: a pydantic
    model's private attributes take part in its ``==``."""
    layout = _LAYOUTS.get(id(space))
    if layout is None:
        layout = _LAYOUTS[id(space)] = _new_layout(space)
        weakref.finalize(space, _LAYOUTS.pop, id(space), None)
    return layout


def _new_layout(space: DesignSpace) -> SpecLayout:
    slots = space.free_specs()
    fixed: dict[str, float] = {}
    chooses: dict[str, str] = {}
    placeholders: set[str] = set()
    for instance in space.instances:
        placeholders.update(
            f"{instance.name}.joint.{spec}"
            for spec in UNUSED_JOINT_SPECS.get(space.joint_kind(instance.name), ())
        )
        part_catalogue = space.chosen_catalogue(instance.name, "part")
        if part_catalogue is not None:
            chooses[instance.name] = part_catalogue
        joint_catalogue = space.chosen_catalogue(instance.name, "joint")
        if joint_catalogue is not None:
            chooses[f"{instance.name}.joint"] = joint_catalogue
        for spec in PART_SPECS:
            value = space.part_spec(instance.name, spec)
            if value is not None and not isinstance(value, Bound):
                fixed[f"{instance.name}.{spec}"] = float(value)
        for spec in JOINT_SPECS:
            value = space.joint_spec(instance.name, spec)
            if not isinstance(value, Bound):
                fixed[f"{instance.name}.joint.{spec}"] = float(value)
    return SpecLayout(
        names=[key for key, _ in slots],
        low=_read_only(np.array([bound.low for _, bound in slots], dtype=np.float64)),
        high=_read_only(np.array([bound.high for _, bound in slots], dtype=np.float64)),
        fixed=fixed,
        structures=[list(s) for s in space.tree_structures()],
        log=_read_only(np.array([bound.log for _, bound in slots], dtype=bool)),
        ties=space.ties(),
        chooses=chooses,
        catalogues={name: dict(c) for name, c in space.catalogues.items()},
        placeholders=frozenset(placeholders),
    )


def _read_only(array: np.ndarray) -> np.ndarray:
    array.setflags(write=False)
    return array


def identity_representation(space: DesignSpace) -> Representation:
    """The representation of a single-structure space: the normalised spec vector."""
    layout = spec_layout(space)
    if len(layout.structures) != 1:
        raise ValueError(
            f"identity representation needs one structure, the space has "
            f"{len(layout.structures)}; build a fused one (adservice.representation)"
        )
    return Representation(
        kind="identity",
        spec_names=layout.names,
        spec_low=layout.low.tolist(),
        spec_high=layout.high.tolist(),
        structures=layout.structures,
        bounds=[[0.0] * layout.size, [1.0] * layout.size],
        info={"dim": layout.size, "n_structures": 1},
    )


def onehot_representation(space: DesignSpace) -> Representation:
    """The plain encoding of a multi-structure space: [one-hot structure, spec vector].

    Every coordinate lies in [0, 1]; the structure is the argmax of the first
    ``n_structures`` coordinates (ties to the first), the specs are the rest. A
    structure's unused spec slots are ignored, so many vectors decode to one design.
    """
    layout = spec_layout(space)
    count = len(layout.structures)
    if count < 2:
        raise ValueError("a one-hot representation needs several structures; use identity")
    dim = count + layout.size
    return Representation(
        kind="onehot",
        spec_names=layout.names,
        spec_low=layout.low.tolist(),
        spec_high=layout.high.tolist(),
        structures=layout.structures,
        bounds=[[0.0] * dim, [1.0] * dim],
        info={"dim": dim, "n_structures": count, "spec_dim": layout.size},
    )


def checked_layout(space: DesignSpace, representation: Representation) -> SpecLayout:
    layout = spec_layout(space)
    if layout.names != representation.spec_names:
        raise ValueError(
            "the representation does not belong to this space: spec names differ "
            f"({representation.spec_names} vs {layout.names})"
        )
    if [list(map(tuple, s)) for s in representation.structures] != [
        list(s) for s in layout.structures
    ]:
        raise ValueError("the representation does not belong to this space: structures differ")
    return layout


def _vector(representation: Representation, vector: Sequence[float] | np.ndarray) -> np.ndarray:
    v = np.asarray(vector, dtype=np.float64)
    dim = len(representation.bounds[0])
    if v.shape != (dim,):
        raise ValueError(f"vector has {v.size} values, the search space has {dim}")
    if not np.all(np.isfinite(v)):
        raise ValueError("vector has non-finite values")
    return v


def structure_of(representation: Representation, vector: Sequence[float] | np.ndarray) -> int:
    """Structure index a vector decodes to: the nearest reference design's."""
    v = _vector(representation, vector)
    if representation.kind == "identity":
        return 0
    if representation.kind == "onehot":
        return int(np.argmax(v[: len(representation.structures)]))
    if representation.kind == "mixed":
        return structure_index_of(v[0], len(representation.structures))
    refs = np.asarray(representation.ref_coords, dtype=np.float64)
    nearest = int(np.argmin(((refs - v) ** 2).sum(axis=1)))
    return int(representation.ref_structure[nearest])


def structure_index_of(value: float, count: int) -> int:
    """The structure a mixed vector's first coordinate names: rounded, kept in range."""
    return int(min(max(math.floor(float(value) + 0.5), 0), count - 1))


def mixed_bounds(structure_count: int, spec_count: int) -> list[list[float]]:
    """The search box of a mixed representation: the structure index, then [0, 1] specs."""
    return [
        [-0.5] + [0.0] * spec_count,
        [structure_count - 0.5] + [1.0] * spec_count,
    ]


def spec_vector(representation: Representation, vector: Sequence[float]) -> tuple[int, np.ndarray]:
    """(structure index, normalised spec vector in [0, 1]) of a search vector."""
    v = _vector(representation, vector)
    if representation.kind == "identity":
        return 0, np.clip(v, 0.0, 1.0)
    if representation.kind == "onehot":
        count = len(representation.structures)
        return structure_of(representation, v), np.clip(v[count:], 0.0, 1.0)
    if representation.kind == "mixed":
        return structure_of(representation, v), np.clip(v[1:], 0.0, 1.0)
    structure = structure_of(representation, v)
    matrix = np.asarray(representation.affine[structure], dtype=np.float64)
    return structure, np.clip(np.append(v, 1.0) @ matrix, 0.0, 1.0)


def decode(space: DesignSpace, representation: Representation, vector: Sequence[float]) -> Design:
    """The design a search vector stands for."""
    layout = checked_layout(space, representation)
    structure, x = spec_vector(representation, vector)
    values = dict(zip(layout.names, layout.denormalise(x).tolist(), strict=True))
    return build_design(space, layout, structure, values)


def build_design(
    space: DesignSpace, layout: SpecLayout, structure: int, values: Mapping[str, float]
) -> Design:
    """A design from a structure index and the free specs' physical values (a log
    spec's value itself, not its coordinate: the URDF writer and the worker's robot
    take the design as it is). A link whose mass comes from ``density`` gets
    ``mass = link_mass(shape, length, radius, density)``, the derived mass everything
    downstream (URDF, simulator, the ``mass`` metric) uses."""
    edges = layout.structures[structure]

    def spec(key: str) -> float:
        return layout.value(key, values)

    children = {child for _, child in edges}
    members: list[str] = []
    for edge in edges:
        for name in edge:
            if name not in members:
                members.append(name)
    root = next(name for name in members if name not in children)
    order = [instance.name for instance in space.instances if instance.name in members]
    links = [
        _link(space, name, spec, layout.choice(name, values) if name in layout.chooses else None)
        for name in order
    ]
    joints: list[Joint] = []
    taken: set[str] = set()
    turned = space.uses_offsets()
    for parent, child in edges:
        name = f"{parent}_{child}"
        while name in taken:
            name += "_"
        taken.add(name)
        theta = spec(f"{child}.joint.axis_theta")
        phi = spec(f"{child}.joint.axis_phi")
        joints.append(
            Joint(
                name=name,
                parent=parent,
                child=child,
                axis=axis_from_angles(theta, phi),
                axis_theta=theta,
                axis_phi=phi,
                position=spec(f"{child}.joint.position"),
                lower=spec(f"{child}.joint.lower"),
                upper=spec(f"{child}.joint.upper"),
                effort=spec(f"{child}.joint.effort"),
                velocity=spec(f"{child}.joint.velocity"),
                choice=layout.choice(f"{child}.joint", values)
                if f"{child}.joint" in layout.chooses
                else None,
                kind=space.joint_kind(child),
                **(
                    {name: spec(f"{child}.joint.{name}") for name in OFFSET_SPECS} if turned else {}
                ),
            )
        )
    return Design(structure_index=structure, root=root, links=links, joints=joints)


def _link(space: DesignSpace, name: str, spec: Callable[[str], float], choice: str | None) -> Link:
    shape = space.parts[space.instance(name).part].shape
    length, radius = spec(f"{name}.length"), spec(f"{name}.radius")
    if space.mass_spec(name) == "density":
        density = spec(f"{name}.density")
        mass = link_mass(shape, length, radius, density)
        return Link(
            name=name,
            shape=shape,
            length=length,
            radius=radius,
            mass=mass,
            density=density,
            choice=choice,
        )
    mass = spec(f"{name}.mass")
    return Link(name=name, shape=shape, length=length, radius=radius, mass=mass, choice=choice)


def axis_from_angles(theta: float, phi: float) -> tuple[float, float, float]:
    """The unit joint axis of (theta, phi), per the convention in adclient.design."""
    return (
        math.sin(theta) * math.cos(phi),
        math.sin(theta) * math.sin(phi),
        math.cos(theta),
    )


def design_params(design: Design) -> dict[str, Any]:
    """A readable, JSON-able summary: structure, then every link's and joint's specs.

    Values are physical, a log spec's too (its coordinate is in the trial's vector):
    these are a trial's ``params``, which the dashboard charts on linear axes as it does
    a box's log params, exports write and ``encode`` reads back. Every link shows its
    ``mass``; a link whose mass comes from ``density`` shows that too, after it (its
    ``mass`` is then derived: ``encode`` checks it, it does not read it). A link not a
    cylinder shows its ``shape``, a joint not revolute its ``kind``."""
    params: dict[str, Any] = {
        "structure": ",".join(f"{parent}-{child}" for parent, child in design.edges()),
        "structure_index": design.structure_index,
        "root": design.root,
    }
    for link in design.links:
        if link.shape != "cylinder":
            params[f"{link.name}.shape"] = link.shape
        if link.choice is not None:
            params[f"{link.name}.choice"] = link.choice
        for spec in PART_SPECS:
            value = getattr(link, spec)
            if value is not None:
                params[f"{link.name}.{spec}"] = float(value)
    for joint in design.joints:
        if joint.kind != "revolute":
            params[f"{joint.child}.joint.kind"] = joint.kind
        if joint.choice is not None:
            params[f"{joint.child}.joint.choice"] = joint.choice
        for spec in JOINT_SPECS:
            value = getattr(joint, spec)
            if value is not None:  # offsets: only where the space turns a joint
                params[f"{joint.child}.joint.{spec}"] = float(value)
        params[f"{joint.child}.joint.axis"] = [float(value) for value in joint.axis]
    return params


def searched_params(space: DesignSpace) -> set[str]:
    """The keys of a design trial's ``params`` (``design_params``) that the search
    chose: each free spec, a catalogue's choice, a free axis, and the structure when
    there are several. The rest the study file fixed, or a tie or mirror derived."""
    keys = set()
    for name in spec_layout(space).names:
        owner, spec = spec_owner(name)
        if spec.startswith("choice."):
            keys.add(f"{owner}.choice")
        elif spec in ("axis_theta", "axis_phi"):
            keys.add(f"{owner}.axis")
        else:
            keys.add(name)
    if len(space.tree_structures()) > 1:
        keys.add("structure")
    return keys


def design_catalogue_totals(space: DesignSpace, design: Design) -> dict[str, float]:
    """The entries of the components a design chose, summed per catalogue
    (``motors.cost``): metrics its study can constrain or optimise."""
    chosen: list[tuple[str, str]] = []
    for link in design.links:
        catalogue = space.chosen_catalogue(link.name, "part")
        if catalogue is not None and link.choice is not None:
            chosen.append((catalogue, link.choice))
    for joint in design.joints:
        if space.joint.choose is not None and joint.choice is not None:
            chosen.append((space.joint.choose, joint.choice))
    return catalogue_totals(chosen, space.catalogues)
