"""Designs and params back to search vectors: ``encode`` (what enqueue, add and
import hand over, checked against the space: ties, catalogue choices, derived masses)
and ``design_values``. The inverse of ``adclient.decode``."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from adclient.catalogues import coordinate
from adclient.decode import PAD, SpecLayout, checked_layout, spec_owner
from adclient.design import DesignSpace
from adclient.designs import Design, Representation
from adclient.specs import (
    JOINT_SPECS,
    PART_SPECS,
    link_mass,
)
from adclient.trees import Edge


def design_values(layout: SpecLayout, design: Design) -> dict[str, float]:
    """The free specs (physical values) a design fills; slots it leaves empty are absent."""
    links = {link.name: link for link in design.links}
    joints = {joint.child: joint for joint in design.joints}
    values: dict[str, float] = {}
    for key in layout.names:
        instance, _, spec = key.partition(".")
        if ".choice." in key:
            owner, entry = key.split(".choice.")
            holder = (joints if owner.endswith(".joint") else links).get(instance)
            if holder is not None and holder.choice is not None:
                values[key] = coordinate(layout.catalogue_of(owner), holder.choice, entry)
            continue
        if spec.startswith("joint."):
            if instance in joints:
                values[key] = float(getattr(joints[instance], spec.removeprefix("joint.")))
        elif instance in links and getattr(links[instance], spec) is not None:
            values[key] = float(getattr(links[instance], spec))
    return values


def _structure_index(layout: SpecLayout, edges: Sequence[Edge]) -> int:
    wanted = frozenset((parent, child) for parent, child in edges)
    for index, structure in enumerate(layout.structures):
        if frozenset(structure) == wanted:
            return index
    raise ValueError(f"structure {list(edges)} is not one of the space's candidate structures")


def encode(
    space: DesignSpace,
    representation: Representation,
    design_or_specs: Design | Mapping[str, Any],
) -> list[float]:
    """A search vector for a design, or for a mapping of spec key -> value.

    Identity and mixed representations: exact (``decode(encode(d))`` gives ``d``
    back, a log spec's value too, to the bit for a decoded design; a mixed vector's
    unused slots hold ``PAD``). Fused
    ones: a vector that decodes to the design's structure and, among those tried
    (the structure's reference designs and the least-squares inverse of its affine
    map), to the specs nearest the design's; exact for reference designs up to the
    affine map's fit. One-hot ones: exact (the structure's coordinate 1, the others
    0). A mapping may name ``structure_index`` (default 0) and must give every free
    spec the structure uses; other known spec keys (as in ``design_params``) are
    ignored, except a derived mass: a ``"<link>.mass"`` given for a link whose mass
    comes from ``density`` must be density times its volume (as ``design_params``
    shows it), else a ValueError naming it.
    """
    layout = checked_layout(space, representation)
    if isinstance(design_or_specs, Design):
        structure = _structure_index(layout, design_or_specs.edges())
        values = design_values(layout, design_or_specs)
    else:
        structure = int(design_or_specs.get("structure_index", 0))
        if not 0 <= structure < len(layout.structures):
            raise ValueError(f"structure_index {structure} out of range")
        values = _chosen_values(layout, structure, design_or_specs)
        for key, value in design_or_specs.items():
            if key in layout.names and ".choice." not in key:
                values[key] = float(value)
    used = layout.used_slots(layout.structures[structure])
    physical = layout.denormalise(np.full(layout.size, PAD))
    for k, key in enumerate(layout.names):
        if not used[k]:
            continue
        if key not in values:
            raise ValueError(f"encode: spec {key!r} is missing")
        value = values[key]
        low, high = layout.low[k], layout.high[k]
        tolerance = 1e-9 * max(1.0, abs(low), abs(high))
        if not (math.isfinite(value) and low - tolerance <= value <= high + tolerance):
            raise ValueError(f"encode: spec {key!r} = {value!r} lies outside [{low}, {high}]")
        physical[k] = min(max(value, low), high)
    if not isinstance(design_or_specs, Design):
        _check_derived_masses(space, layout, structure, values, design_or_specs)
        _check_derived_values(layout, structure, values, design_or_specs)
    x = np.where(used, layout.normalise(physical), PAD)
    if representation.kind == "identity":
        return x.tolist()
    if representation.kind == "onehot":
        onehot = np.zeros(len(layout.structures))
        onehot[structure] = 1.0
        return [*onehot.tolist(), *x.tolist()]
    if representation.kind == "mixed":
        return [float(structure), *x.tolist()]
    return _encode_fused(representation, structure, x, used).tolist()


def _check_derived_masses(
    space: DesignSpace,
    layout: SpecLayout,
    structure: int,
    values: Mapping[str, float],
    given: Mapping[str, Any],
) -> None:
    """A mass given for a link whose mass is derived from its density must be that mass
    (to 1e-9 relative): the params the server showed are, a mass of one's own is not
    this design (ignoring it would store a robot of another mass)."""
    members = {name for edge in layout.structures[structure] for name in edge}
    for instance in space.instances:
        key = f"{instance.name}.mass"
        if instance.name not in members or key not in given:
            continue
        if space.mass_spec(instance.name) != "density":
            continue

        def spec(name: str, link: str = instance.name) -> float:
            return layout.value(f"{link}.{name}", values)

        try:
            derived = link_mass(
                space.parts[instance.part].shape, spec("length"), spec("radius"), spec("density")
            )
        except KeyError:
            continue  # a missing spec: encode names it next
        mass = given[key]
        if (
            isinstance(mass, bool)
            or not isinstance(mass, int | float)
            or not math.isclose(mass, derived, rel_tol=1e-9, abs_tol=0.0)
        ):
            raise ValueError(
                f"encode: spec {key!r} = {mass!r} is not this link's mass: it is given by "
                f"density, so its mass is density x volume = {derived!r}; leave {key!r} "
                "out or give that value"
            )


def _chosen_values(
    layout: SpecLayout, structure: int, given: Mapping[str, Any]
) -> dict[str, float]:
    """The choice slots of the components ``given`` names (``b.joint.choice: xm430``),
    for the choosing parts and joints whose slots the structure uses."""
    used = dict(zip(layout.names, layout.used_slots(layout.structures[structure]), strict=True))
    values: dict[str, float] = {}
    for key in layout.names:
        if ".choice." not in key or not used[key]:
            continue
        owner, entry = key.split(".choice.")
        catalogue = layout.catalogue_of(owner)
        name = given.get(f"{owner}.choice")
        if name is None:
            raise ValueError(f"encode: spec {owner + '.choice'!r} is missing")
        if name not in catalogue:
            raise ValueError(
                f"encode: {owner}.choice: {name!r} is no component of catalogue "
                f"{layout.chooses[owner]!r} (components: {', '.join(catalogue)})"
            )
        values[key] = coordinate(catalogue, name, entry)
    return values


def _check_derived_values(
    layout: SpecLayout, structure: int, values: Mapping[str, float], given: Mapping[str, Any]
) -> None:
    """A spec given for a tied instance must be its source's (a mirrored axis angle
    mirrored), one a catalogue sets its component's, to 1e-9, and a choice the one the
    design has: the params the server showed are; another value is a design the space
    cannot hold (ignoring it would store another robot)."""
    members = {name for edge in layout.structures[structure] for name in edge}
    spec_names = {*PART_SPECS, *(f"joint.{name}" for name in JOINT_SPECS)}
    for key, value in given.items():
        instance, _, rest = key.partition(".")
        owner, entry = spec_owner(key)
        if instance not in members:
            continue
        if rest in ("choice", "joint.choice") and owner in layout.chooses:
            chosen = layout.choice(owner, values)
            if value != chosen:
                raise ValueError(
                    f"encode: {key} = {value!r} is not the component this design has: {chosen!r}"
                )
            continue
        derived = instance in layout.ties or (
            owner in layout.chooses
            and entry in layout.catalogue_of(owner)[layout.first_component(owner)]
        )
        if not derived or rest not in spec_names:
            continue
        try:
            expected = layout.value(key, values)
        except KeyError:
            continue  # not a spec of this link (the mass spec it does not use)
        if (
            isinstance(value, bool)
            or not isinstance(value, int | float)
            or not math.isclose(value, expected, rel_tol=1e-9, abs_tol=1e-12)
        ):
            if instance in layout.ties:
                source = layout.ties[instance].source
                why = (
                    f"{instance!r} is tied to {source!r} (same_as), so its specs are those "
                    f"of {source!r}"
                )
            else:
                why = (
                    f"the component {layout.choice(owner, values)!r} of catalogue "
                    f"{layout.chooses[owner]!r} sets it"
                )
            raise ValueError(
                f"encode: spec {key!r} = {value!r} differs from {expected!r}: {why}; leave "
                f"{key!r} out or give that value"
            )


def _encode_fused(
    representation: Representation, structure: int, x: np.ndarray, used: np.ndarray
) -> np.ndarray:
    refs = np.asarray(representation.ref_coords, dtype=np.float64)
    labels = np.asarray(representation.ref_structure)
    matrix = np.asarray(representation.affine[structure], dtype=np.float64)
    linear, offset = matrix[:-1], matrix[-1]
    # the vectors v with v @ linear[:, used] == x[used] - offset[used] form an affine
    # subspace (when reachable); project the structure's references onto it, so some
    # candidate both reproduces the specs and lies near its own structure
    own = refs[labels == structure]
    if not used.any():
        return own[0]
    system = linear[:, used].T
    particular, *_ = np.linalg.lstsq(system, (x - offset)[used], rcond=None)
    _, singular, rows = np.linalg.svd(system)
    rank = int(np.sum(singular > 1e-10 * max(float(singular.max()), 1e-300)))
    null = rows[rank:].T
    projected = particular + ((own - particular) @ null) @ null.T
    low, high = np.asarray(representation.bounds[0]), np.asarray(representation.bounds[1])
    candidates = [*np.clip(projected, low, high), np.clip(particular, low, high), *own]
    best, best_error = None, math.inf
    for v in candidates:
        nearest = int(np.argmin(((refs - v) ** 2).sum(axis=1)))
        if labels[nearest] != structure:
            continue
        decoded = np.clip(np.append(v, 1.0) @ matrix, 0.0, 1.0)
        error = float(np.abs(decoded - x)[used].max(initial=0.0))
        if error < best_error:
            best, best_error = v, error
    if best is None:  # unreachable: a reference's own coordinates decode to its structure
        raise ValueError(f"no vector decodes to structure {structure}")
    return best
