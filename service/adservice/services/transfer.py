"""Controller transfer: which evaluated design a job's controller starts from
(``task.transfer: nearest``), and the study's shared controller (``shared``).

The repository (:mod:`adservice.repository.transfer`) returns the candidate sources,
rows of the study's complete, feasible trials whose checkpoint a worker uploaded under
the lease that completed them, ranked by the study's objective; the choice is made
here, by pure functions of those rows and the study's configuration: of the job's
design's own tree (so the same observation and action spaces), the ``transfer_among``
best (for several objectives: the non-dominated ones), and of those the nearest by the
normalised spec distance. The choice runs when a job is leased, never on the ask/tell
hot path of a study without transfer.

A study with ``task.transfer: shared`` keeps one controller (:mod:`adservice.repository.shared`):
a job carries its current version, and the worker that trained a design advances it
with :func:`advance_shared`.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence

import numpy as np

from adclient.decode import spec_vector, used_slots
from adclient.designs import Representation
from adclient.objectives import Outcomes, pareto_front
from adclient.pruning import CHECKPOINT_ARTIFACT
from adclient.schemas import SharedUpdate, SharedVersion, TransferSource, Trial
from adclient.ties import Tie
from adservice.db import Database
from adservice.models import SharedControllerRow
from adservice.principals import Principal
from adservice.repository import shared as shared_repo
from adservice.repository.studies import get_study
from adservice.repository.transfer import SourceRow, source_rows
from adservice.services.configs import StudyConfig


def transfer_source(db: Database, *, trial: Trial, config: StudyConfig) -> TransferSource | None:
    """Where the leased ``trial``'s controller starts, or None (transfer off, a trial
    resuming from its own checkpoint, or no candidate of its tree). Errors decoding a
    stored design raise: the caller leases the job without a source."""
    task = config.task
    if task is None or task.transfer == "none" or trial.checkpoint is not None:
        return None
    with db.read() as session:
        return choose_source(
            trial.vector,
            source_rows(session, trial=trial, outcomes=config.outcomes),
            among=task.transfer_among,
            representation=config.representation,
            ties=config.design_space.ties() if config.design_space else {},
            bounds=config.bounds,
            outcomes=config.outcomes,
        )


def shared_version(db: Database, *, study_id: int) -> SharedVersion | None:
    """The study's current shared controller, None before its first version (or when
    it keeps none); NotFoundError for a study that is not there."""
    with db.read() as session:
        row = shared_repo.current_shared(session, study_id=study_id)
        if row is None:
            get_study(session, study_id=study_id)
            return None
        return _version(row)


def advance_shared(
    db: Database, *, trial_id: int, body: SharedUpdate, caller: Principal
) -> SharedVersion:
    """Make the held trial's uploaded update the study's next version (see
    :func:`adservice.repository.shared.advance_shared`)."""
    with db.write() as session:
        row = shared_repo.advance_shared(
            session,
            trial_id=trial_id,
            worker_id=body.worker_id,
            base_version=body.base_version,
            caller=caller,
        )
        return _version(row)


def _version(row: SharedControllerRow | shared_repo.MadeVersion) -> SharedVersion:
    return SharedVersion(version=row.version, trial_id=row.trial_id, updated_at=row.updated_at)


def choose_source(
    vector: Sequence[float],
    rows: Iterable[SourceRow],
    *,
    among: int,
    representation: Representation | None,
    ties: Mapping[str, Tie],
    bounds: np.ndarray,
    outcomes: Outcomes,
) -> TransferSource | None:
    """The source for a design at ``vector`` among ``rows`` (the best first for one
    objective, as :func:`adservice.repository.transfer.source_rows` returns them), or
    None when none is of its tree."""
    tree, specs = tree_and_specs(representation, bounds, vector)
    best = best_of_tree(
        rows,
        tree=tree,
        among=among,
        representation=representation,
        bounds=bounds,
        outcomes=outcomes,
    )
    if not best:
        return None
    used = compared_coordinates(representation, ties, tree, len(specs))
    index, distance = nearest(specs, [other for _, other in best], used)
    return TransferSource(trial_id=best[index][0], artifact=CHECKPOINT_ARTIFACT, distance=distance)


def best_of_tree(
    rows: Iterable[SourceRow],
    *,
    tree: int,
    among: int,
    representation: Representation | None,
    bounds: np.ndarray,
    outcomes: Outcomes,
) -> list[tuple[int, np.ndarray]]:
    """(trial id, specs) of the best rows of ``tree``: for one objective the first
    ``among`` (``rows`` come best first, read no further), for several the
    non-dominated ones among those with every value."""
    best: list[tuple[int, np.ndarray]] = []
    points: list[Sequence[float]] = []  # several objectives: the values of each of ``best``
    for row in rows:
        other_tree, other_specs = tree_and_specs(representation, bounds, row.vector)
        if other_tree != tree:
            continue
        if outcomes.multi:
            values = [value for value in row.values or [] if value is not None]
            if len(values) == outcomes.count:  # every value
                best.append((row.id, other_specs))
                points.append(values)
        else:
            best.append((row.id, other_specs))
            if len(best) == among:
                break
    if outcomes.multi:
        best = [best[index] for index in pareto_front(points, outcomes.signs)]
    return best


def nearest(specs: np.ndarray, others: Sequence[np.ndarray], used: np.ndarray) -> tuple[int, float]:
    """(index, distance) of the nearest of ``others`` to ``specs``: the root mean square
    difference over the ``used`` coordinates (0 when none is used), the first on a tie."""
    distances = [
        float(np.sqrt(np.mean((other[used] - specs[used]) ** 2))) if used.any() else 0.0
        for other in others
    ]
    index = int(np.argmin(distances))
    return index, distances[index]


def tree_and_specs(
    representation: Representation | None, bounds: np.ndarray, vector: Sequence[float]
) -> tuple[int, np.ndarray]:
    """(tree, coordinates in [0, 1]) of a trial's vector (a box is one tree)."""
    if representation is None:
        low, high = bounds
        span = np.where(high > low, high - low, 1.0)
        return 0, np.clip((np.asarray(vector, dtype=np.float64) - low) / span, 0.0, 1.0)
    return spec_vector(representation, vector)


def compared_coordinates(
    representation: Representation | None, ties: Mapping[str, Tie], tree: int, size: int
) -> np.ndarray:
    """The coordinates a tree's designs are compared on (a box: all of them)."""
    if representation is None:
        return np.ones(size, dtype=bool)
    return used_slots(representation.spec_names, representation.structures[tree], ties)
