"""Catalogues of components (issue 28): a part or a joint that says ``choose: motors``
is one of the catalogue's components, whose entries set its specs (a motor's
``effort`` and ``velocity``) and carry the rest along (``mass``, ``cost``).

The search relates components by what they are, not as unrelated categories: a
choosing part or joint searches one coordinate per entry that varies across the
catalogue (``choice_slots``; on a log scale when the entry is positive and spans more
than a decade), and a point decodes to the component nearest it in those normalised
coordinates (``nearest``). Two similar motors are near each other, so a model that
learned one is good predicts the other is too, and every proposer handles the choice.

A design's components' other entries add up per catalogue as metrics
(``catalogue_totals``: ``motors.cost``), which a study can constrain or optimise.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

NAME_PATTERN = r"^[A-Za-z][A-Za-z0-9_\-]{0,63}$"
LOG_SPAN = 10.0
"""An entry whose largest value is more than this many times its smallest (all
positive) is searched on a log scale."""

Catalogue = Mapping[str, Mapping[str, float]]
"""Component name -> entry name -> value."""


@dataclass(frozen=True)
class ChoiceSlot:
    """One searched entry of a catalogue: its values span [low, high], on a log scale
    when ``log``."""

    key: str
    low: float
    high: float
    log: bool


def check_catalogue(name: str, catalogue: Catalogue) -> None:
    """A catalogue has components of valid names, each with the same finite entries."""
    where = f"catalogues.{name}"
    if re.fullmatch(NAME_PATTERN, name) is None:
        raise ValueError(f"catalogues: name {name!r} must match {NAME_PATTERN}")
    if not catalogue:
        raise ValueError(f"{where}: a catalogue needs at least one component")
    first_name, first = next(iter(catalogue.items()))
    if not first:
        raise ValueError(f"{where}.{first_name}: a component needs at least one entry")
    for component, entries in catalogue.items():
        if re.fullmatch(NAME_PATTERN, component) is None:
            raise ValueError(f"{where}: component name {component!r} must match {NAME_PATTERN}")
        if set(entries) != set(first):
            raise ValueError(
                f"{where}.{component}: entries {sorted(entries)} differ from "
                f"{first_name}'s {sorted(first)}; every component of a catalogue names the "
                "same entries"
            )
        for key, value in entries.items():
            if re.fullmatch(NAME_PATTERN, key) is None:
                raise ValueError(
                    f"{where}.{component}: entry name {key!r} must match {NAME_PATTERN}"
                )
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ValueError(f"{where}.{component}.{key}: an entry is a number, got {value!r}")
            if not math.isfinite(value):
                raise ValueError(f"{where}.{component}.{key}: must be finite, got {value!r}")


def entry_keys(catalogue: Catalogue) -> list[str]:
    """The entries every component names, in the first component's order."""
    return list(next(iter(catalogue.values())))


def choice_slots(catalogue: Catalogue) -> list[ChoiceSlot]:
    """The entries that differ between components: what the search moves through."""
    slots = []
    for key in entry_keys(catalogue):
        values = [float(entries[key]) for entries in catalogue.values()]
        low, high = min(values), max(values)
        if high > low:
            slots.append(ChoiceSlot(key, low, high, low > 0 and high > LOG_SPAN * low))
    return slots


def _unit(slot: ChoiceSlot, value: float) -> float:
    if slot.log:
        return (math.log(value) - math.log(slot.low)) / (math.log(slot.high) - math.log(slot.low))
    return (value - slot.low) / (slot.high - slot.low)


def nearest(catalogue: Catalogue, point: Mapping[str, float]) -> str:
    """The component nearest ``point`` (entry -> value, the searched entries) in the
    normalised coordinates; the first in the catalogue's order on a tie."""
    slots = choice_slots(catalogue)
    best, best_distance = next(iter(catalogue)), math.inf
    for component, entries in catalogue.items():
        distance = math.fsum(
            (_unit(slot, float(entries[slot.key])) - _unit(slot, point[slot.key])) ** 2
            for slot in slots
        )
        if distance < best_distance:
            best, best_distance = component, distance
    return best


def catalogue_totals(
    chosen: Sequence[tuple[str, str]], catalogues: Mapping[str, Catalogue]
) -> dict[str, float]:
    """Each catalogue's entries summed over the components a design chose (``(catalogue,
    component)`` pairs, once per part or joint): ``{"motors.cost": 720.0, ...}``."""
    totals: dict[str, float] = {}
    for catalogue, component in chosen:
        for key, value in catalogues[catalogue][component].items():
            name = f"{catalogue}.{key}"
            totals[name] = totals.get(name, 0.0) + float(value)
    return totals
