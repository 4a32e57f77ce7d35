"""Catalogues of components: a part or a joint that says ``choose: motors``
is one of the catalogue's components, whose entries set its specs (a motor's
``effort`` and ``velocity``) and carry the rest along (``mass``, ``cost``).

The search relates components by what they are, not as unrelated categories. Each
entry that varies across the catalogue is normalised to [0, 1] (on a log scale when it
is positive and spans more than a decade); the components' normalised entry vectors
are embedded by their principal components, as many as hold ``EMBEDDING_VARIANCE`` of
their spread (``coordinates``). A choosing part or joint searches those coordinates
(``choice_slots``), and a point decodes to the component nearest it (``nearest``).
Two similar motors are near each other, so a model that learned one is good predicts
the other is too; the few coordinates keep the search as small as a categorical's when
the entries go together (a stronger motor is heavier and dearer); every proposer
handles the choice.

A design's components' other entries add up per catalogue as metrics
(``catalogue_totals``: ``motors.cost``), which a study can constrain or optimise.
"""

from __future__ import annotations

import functools
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

NAME_PATTERN = r"^[A-Za-z][A-Za-z0-9_\-]{0,63}$"
LOG_SPAN = 10.0
"""An entry whose largest value is more than this many times its smallest (all
positive) is compared on a log scale."""
EMBEDDING_VARIANCE = 0.9
"""The share of the components' spread (variance of their normalised entries) the
embedding keeps: its dimensions are the fewest principal components that hold it."""

Catalogue = Mapping[str, Mapping[str, float]]
"""Component name -> entry name -> value."""


@dataclass(frozen=True)
class ChoiceSlot:
    """One searched coordinate of a catalogue's embedding (``"0"``, ``"1"``, ...): the
    components' values of it span [low, high]."""

    key: str
    low: float
    high: float
    log: bool = False


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


def _normalised(catalogue: Catalogue) -> np.ndarray:
    """(components x entries that vary) each entry scaled to [0, 1], on a log scale when
    positive and spanning more than ``LOG_SPAN``."""
    columns = []
    for key in entry_keys(catalogue):
        values = np.array([float(entries[key]) for entries in catalogue.values()])
        low, high = values.min(), values.max()
        if not high > low:
            continue
        if low > 0 and high > LOG_SPAN * low:
            values, low, high = np.log(values), np.log(low), np.log(high)
        columns.append((values - low) / (high - low))
    return np.column_stack(columns) if columns else np.zeros((len(catalogue), 0))


def coordinates(catalogue: Catalogue) -> dict[str, tuple[float, ...]]:
    """Each component's place in the catalogue's embedding (see the module docstring);
    the axes' signs fixed so the largest loading is positive, so every process agrees.
    Computed once per catalogue: decoding a design asks for it per spec it sets."""
    frozen = tuple((name, tuple(entries.items())) for name, entries in catalogue.items())
    return dict(_embedding(frozen))


@functools.lru_cache(maxsize=256)
def _embedding(
    frozen: tuple[tuple[str, tuple[tuple[str, float], ...]], ...],
) -> tuple[tuple[str, tuple[float, ...]], ...]:
    catalogue = {name: dict(entries) for name, entries in frozen}
    matrix = _normalised(catalogue)
    centred = matrix - matrix.mean(axis=0) if matrix.size else matrix
    dims = 0
    embedded = np.zeros((len(catalogue), 0))
    if centred.size and np.any(centred):
        _, singular, axes = np.linalg.svd(centred, full_matrices=False)
        share = np.cumsum(singular**2) / np.sum(singular**2)
        dims = int(np.searchsorted(share, EMBEDDING_VARIANCE - 1e-12) + 1)
        axes = axes[:dims]
        signs = np.sign(axes[np.arange(dims), np.argmax(np.abs(axes), axis=1)])
        embedded = centred @ (axes * signs[:, None]).T
    rows = zip(catalogue, embedded, strict=True)
    return tuple((name, tuple(float(v) for v in row)) for name, row in rows)


def choice_slots(catalogue: Catalogue) -> list[ChoiceSlot]:
    """The embedding's coordinates: what the search moves through."""
    points = np.array(list(coordinates(catalogue).values()))
    if points.size == 0:
        return []
    return [
        ChoiceSlot(str(d), float(points[:, d].min()), float(points[:, d].max()))
        for d in range(points.shape[1])
        if points[:, d].max() > points[:, d].min()
    ]


def coordinate(catalogue: Catalogue, component: str, key: str) -> float:
    """A component's value of the embedding coordinate ``key`` (a ``ChoiceSlot.key``)."""
    return coordinates(catalogue)[component][int(key)]


def nearest(catalogue: Catalogue, point: Mapping[str, float]) -> str:
    """The component nearest ``point`` (slot key -> coordinate) in the embedding; the
    first in the catalogue's order on a tie."""
    slots = choice_slots(catalogue)
    best, best_distance = next(iter(catalogue)), math.inf
    for component, place in coordinates(catalogue).items():
        distance = math.fsum((place[int(slot.key)] - point[slot.key]) ** 2 for slot in slots)
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
