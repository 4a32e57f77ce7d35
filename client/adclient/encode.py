"""Designs and params back to search vectors: ``encode`` (what enqueue, add and
import hand over, checked against the space: ties, catalogue choices, derived masses)
and ``design_values``. The inverse of ``adclient.decode``."""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from functools import partial
from typing import Any

import numpy as np

from adclient.catalogues import coordinate
from adclient.decode import NORMALISE_ULPS, PAD, SpecLayout, checked_layout, spec_owner
from adclient.design import DesignSpace
from adclient.designs import Design, Joint, Link, Representation
from adclient.specs import (
    JOINT_SPECS,
    PART_SPECS,
    link_mass,
)
from adclient.ties import Tie, mirrored_angle, unmirrored_angle
from adclient.trees import Edge


def design_values(layout: SpecLayout, design: Design) -> dict[str, float]:
    """The free specs (physical values) a design fills; slots it leaves empty are absent."""
    standing_in = _stand_in_values(layout, design.edges(), design)
    values: dict[str, float] = {}
    for key in layout.names:
        instance = key.partition(".")[0]
        owner, entry = spec_owner(key)
        if entry.startswith("choice."):
            chosen_key = f"{owner}.choice"
            chosen = standing_in.get(chosen_key, _shown(design, instance, chosen_key))
            if chosen is not None:
                slot = entry.removeprefix("choice.")
                values[key] = coordinate(layout.catalogue_of(owner), chosen, slot)
            continue
        value = standing_in.get(key, _shown(design, instance, key))
        if value is not None:
            values[key] = float(value)
    return values


def _shown(design_or_specs: Design | Mapping[str, Any], instance: str, key: str) -> Any:
    """What a design or params show for one of an instance's specs (``"b.length"``,
    ``"b.joint.axis_theta"``, ``"b.joint.choice"``); None for nothing."""
    if not isinstance(design_or_specs, Design):
        return design_or_specs.get(key)
    rest = key.partition(".")[2]
    if rest.startswith("joint."):
        joints = (joint for joint in design_or_specs.joints if joint.child == instance)
        holder: Joint | Link | None = next(joints, None)
    else:
        holder = next((link for link in design_or_specs.links if link.name == instance), None)
    return None if holder is None else getattr(holder, rest.removeprefix("joint."), None)


def _stand_in_instances(layout: SpecLayout, edges: Sequence[Edge]) -> dict[str, list[str]]:
    """Where a structure uses a tie source's slots for its tied instances but has no
    link of the source (it is absent) or no joint (it is the root, or absent), the tied
    instances there that have one, whose specs show them: owner (``"a"`` for a link,
    ``"a.joint"`` for a joint) -> instances."""
    members = {name for edge in edges for name in edge}
    children = {child for _, child in edges}
    found: dict[str, list[str]] = {}
    for name, tie in layout.ties.items():
        if name in members and tie.source not in members:
            found.setdefault(tie.source, []).append(name)
        if name in children and tie.source not in children:
            found.setdefault(f"{tie.source}.joint", []).append(name)
    return found


def _gives_back(spec: str, tie: Tie) -> bool:
    """Whether a tie's mirroring of ``spec`` undoes to the bit (unchanged or negated)."""
    return abs(mirrored_angle(spec, 1.0, tie)) == 1.0


def _stand_in_values(
    layout: SpecLayout, edges: Sequence[Edge], design_or_specs: Design | Mapping[str, Any]
) -> dict[str, Any]:
    """A tie source's specs and choices the structure has no link or joint of it to
    show (``_stand_in_instances``), read from a tied instance's (an axis angle
    unmirrored) that is not its own (``joint_overrides.position``), one whose mirroring
    undoes to the bit first: ``{"a.joint.axis_theta": 0.3, "a.joint.choice": "xm430"}``."""
    found: dict[str, Any] = {}
    for owner, instances in _stand_in_instances(layout, edges).items():
        source = owner.removesuffix(".joint")
        joint = owner.endswith(".joint")
        specs = [*JOINT_SPECS, "choice"] if joint else [*PART_SPECS, "choice"]
        for spec in specs:
            rest = f"joint.{spec}" if joint else spec
            for instance in sorted(instances, key=lambda i: not _gives_back(spec, layout.ties[i])):
                if spec in layout.ties[instance].own:
                    continue
                value = _shown(design_or_specs, instance, f"{instance}.{rest}")
                if value is None:
                    continue
                if joint and isinstance(value, int | float) and not isinstance(value, bool):
                    value = unmirrored_angle(spec, float(value), layout.ties[instance])
                found[f"{source}.{rest}"] = value
                break
    return found


def _shown_exactly(
    layout: SpecLayout,
    edges: Sequence[Edge],
    design_or_specs: Design | Mapping[str, Any],
    x: np.ndarray,
) -> None:
    """Nudge (in place) each normalised slot of ``x`` read from mirrored stand-ins'
    axis angles, by at most ``NORMALISE_ULPS`` floats each way, to one that decodes to
    the angles they showed, to the bit where one does (``pi - t`` rounds, so the
    unmirrored value's own slot may show an ulp off)."""
    for owner, instances in _stand_in_instances(layout, edges).items():
        for spec in ("axis_theta", "axis_phi"):
            key = f"{owner}.{spec}"
            if key not in layout.names:
                continue
            shown = [
                (layout.ties[instance], value)
                for instance in instances
                if isinstance(
                    value := _shown(design_or_specs, instance, f"{instance}.joint.{spec}"), float
                )
            ]
            if all(_gives_back(spec, tie) for tie, _ in shown):
                continue
            k = layout.names.index(key)
            x[k] = _nearest_slot(float(x[k]), partial(_shown_error, layout, x, k, spec, shown))


def _shown_error(
    layout: SpecLayout,
    x: np.ndarray,
    k: int,
    spec: str,
    shown: Sequence[tuple[Tie, float]],
    slot: float,
) -> float:
    """How far ``x`` with ``slot`` at ``k`` decodes from the mirrored angles ``shown``."""
    trial = x.copy()
    trial[k] = slot
    value = float(layout.denormalise(trial)[k])
    return max(abs(mirrored_angle(spec, value, tie) - seen) for tie, seen in shown)


def _nearest_slot(slot: float, error: Callable[[float], float]) -> float:
    """Of ``slot`` and its ``NORMALISE_ULPS`` neighbouring floats each way, the one of
    least ``error`` (the first 0 found)."""
    best, best_error = slot, error(slot)
    for direction in (-np.inf, np.inf):
        near = slot
        for _ in range(NORMALISE_ULPS):
            if best_error == 0.0:
                return best
            near = float(np.clip(np.nextafter(near, direction), 0.0, 1.0))
            near_error = error(near)
            if near_error < best_error:
                best, best_error = near, near_error
    return best


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
    spec the structure uses (a tie source's that has no link or joint there, on an
    instance tied to it, as params show it); other known spec keys (as in
    ``design_params``) are ignored, except a derived mass: a ``"<link>.mass"`` given
    for a link whose mass comes from ``density`` must be density times its volume (as
    ``design_params`` shows it), else a ValueError naming it.
    """
    layout = checked_layout(space, representation)
    if isinstance(design_or_specs, Design):
        structure = _structure_index(layout, design_or_specs.edges())
        values = design_values(layout, design_or_specs)
    else:
        structure = int(design_or_specs.get("structure_index", 0))
        if not 0 <= structure < len(layout.structures):
            raise ValueError(f"structure_index {structure} out of range")
        edges = layout.structures[structure]
        design_or_specs = {**_stand_in_values(layout, edges, design_or_specs), **design_or_specs}
        values = _chosen_values(layout, structure, design_or_specs)
        for key, value in design_or_specs.items():
            if key in layout.names and ".choice." not in key:
                values[key] = _spec_number(layout, structure, key, value)
    used = layout.used_slots(layout.structures[structure])
    physical = layout.denormalise(np.full(layout.size, PAD))
    for k, key in enumerate(layout.names):
        if not used[k]:
            continue
        if key not in values:
            raise ValueError(f"encode: spec {_named(layout, structure, key)} is missing")
        value = values[key]
        low, high = layout.low[k], layout.high[k]
        tolerance = 1e-9 * max(1.0, abs(low), abs(high))
        if not (math.isfinite(value) and low - tolerance <= value <= high + tolerance):
            raise ValueError(
                f"encode: spec {_named(layout, structure, key)} = {value!r} lies outside "
                f"[{low}, {high}]"
            )
        physical[k] = min(max(value, low), high)
    if not isinstance(design_or_specs, Design):
        _check_derived_masses(space, layout, structure, values, design_or_specs)
        _check_derived_values(layout, structure, values, design_or_specs)
    x = np.where(used, layout.normalise(physical), PAD)
    _shown_exactly(layout, layout.structures[structure], design_or_specs, x)
    if representation.kind == "identity":
        return x.tolist()
    if representation.kind == "onehot":
        onehot = np.zeros(len(layout.structures))
        onehot[structure] = 1.0
        return [*onehot.tolist(), *x.tolist()]
    if representation.kind == "mixed":
        return [float(structure), *x.tolist()]
    return _encode_fused(representation, structure, x, used).tolist()


def _named(layout: SpecLayout, structure: int, key: str) -> str:
    """A spec key as a message names it: a tie source's its stand-in shows, as shown."""
    owner, entry = spec_owner(key)
    instances = [
        instance
        for instance in _stand_in_instances(layout, layout.structures[structure]).get(owner, [])
        if entry.partition(".")[0] not in layout.ties[instance].own
    ]
    if not instances:
        return repr(key)
    source = owner.removesuffix(".joint")
    what = "joint" if owner.endswith(".joint") else "link"
    return (
        f"{key!r}, given as {instances[0] + key.removeprefix(source)!r} ({instances[0]!r} "
        f"is tied to {source!r}, which has no {what} in this structure)"
    )


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
            raise ValueError(
                f"encode: spec {_named(layout, structure, owner + '.choice')} is missing"
            )
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


def _spec_number(layout: SpecLayout, structure: int, key: str, value: object) -> float:
    """A spec's given value as a float, or a ValueError naming the spec: ``float``
    raises TypeError for a list and OverflowError for an integer past the float range,
    which a server answered with 500."""
    try:
        return float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError, OverflowError):
        raise ValueError(
            f"encode: spec {_named(layout, structure, key)} is not a finite number"
        ) from None
