"""Repository of controller transfer (``task.transfer: nearest``): which evaluated
design a job's controller starts from, and recording where a trial started.

Same conventions as every module of :mod:`adservice.repository` (an open session,
keyword-only arguments, domain errors). A source is a complete trial of the same study
whose checkpoint artifact a worker uploaded under the lease that completed it (never an
owner's or a user token's upload, nor an earlier lease's: see
:func:`adservice.repository.artifacts.trusted_checkpoint`), of the same tree as the
job's design (so the same observation and action spaces) and feasible under the study's
constraints, among the ``transfer_among`` best of that tree (for several objectives:
its non-dominated designs); of those, the nearest by the normalised spec distance. The
choice runs when a job is leased, never on the ask/tell hot path of a study without
transfer.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import sqlalchemy as sa
from sqlalchemy.orm import Session

from adclient.decode import spec_vector, used_slots
from adclient.designs import Representation
from adclient.objectives import Outcomes, pareto_front
from adclient.pruning import CHECKPOINT_ARTIFACT
from adclient.schemas import TaskConfig, TransferSource, Trial, TrialState
from adclient.ties import Tie
from adservice.errors import InvalidError
from adservice.models import ArtifactRow, StudyRow, TrialRow
from adservice.repository.artifacts import trusted_checkpoint

SCANNED_SOURCES = 2000
"""The most finished trials with a checkpoint a lease looks through (for one objective
the best first, for several the newest first)."""


def transfer_source(
    session: Session,
    *,
    trial: Trial,
    task: TaskConfig,
    representation: Representation | None,
    ties: Mapping[str, Tie],
    bounds: np.ndarray,
    outcomes: Outcomes,
) -> TransferSource | None:
    """Where ``trial``'s controller starts, or None (transfer off, a trial resuming
    from its own checkpoint, or no feasible evaluated design of its tree with a
    checkpoint among those scanned). For several objectives the best of a tree are its
    non-dominated designs."""
    if task.transfer == "none" or trial.checkpoint is not None:
        return None
    # several objectives rank by ``values``; one by ``value``, in the query's order
    columns = [TrialRow.id, TrialRow.vector] + ([TrialRow.values] if outcomes.multi else [])
    query = (
        sa.select(*columns)
        .join(ArtifactRow, ArtifactRow.trial_id == TrialRow.id)
        .where(
            TrialRow.study_id == trial.study_id,
            TrialRow.id != trial.id,
            TrialRow.state == TrialState.complete.value,
            sa.or_(TrialRow.feasible.is_(None), TrialRow.feasible.is_(True)),
            ArtifactRow.name == CHECKPOINT_ARTIFACT,
            # by a worker, under the lease that completed: a promoted trial whose final
            # upload failed still holds its rung's checkpoint, which is no final controller
            trusted_checkpoint(TrialRow.leases),
        )
        .limit(SCANNED_SOURCES)
    )
    if outcomes.multi:
        query = query.where(TrialRow.values.is_not(None)).order_by(TrialRow.id.desc())
    else:
        maximize = outcomes.signs[0] > 0
        order = TrialRow.value.desc() if maximize else TrialRow.value.asc()
        query = query.where(TrialRow.value.is_not(None)).order_by(order, TrialRow.id)
    tree, specs = _tree_and_specs(representation, bounds, trial.vector)
    best: list[tuple[int, np.ndarray]] = []
    points: list[list[float]] = []  # several objectives: the values of each of ``best``
    for row in session.execute(query):
        other_tree, other_specs = _tree_and_specs(representation, bounds, row.vector)
        if other_tree != tree:
            continue
        if outcomes.multi:
            if len(row.values) == outcomes.count and None not in row.values:
                best.append((row.id, other_specs))
                points.append(row.values)
        else:
            best.append((row.id, other_specs))
            if len(best) == task.transfer_among:
                break
    if outcomes.multi:
        best = [best[index] for index in pareto_front(points, outcomes.signs)]
    if not best:
        return None
    used = _used(representation, ties, tree, len(specs))
    distances = [
        float(np.sqrt(np.mean((other[used] - specs[used]) ** 2))) if used.any() else 0.0
        for _, other in best
    ]
    nearest = int(np.argmin(distances))
    return TransferSource(
        trial_id=best[nearest][0], artifact=CHECKPOINT_ARTIFACT, distance=distances[nearest]
    )


def _tree_and_specs(
    representation: Representation | None, bounds: np.ndarray, vector: Sequence[float]
) -> tuple[int, np.ndarray]:
    """(tree, coordinates in [0, 1]) of a trial's vector (a box is one tree)."""
    if representation is None:
        low, high = bounds
        span = np.where(high > low, high - low, 1.0)
        return 0, np.clip((np.asarray(vector, dtype=np.float64) - low) / span, 0.0, 1.0)
    return spec_vector(representation, vector)


def _used(
    representation: Representation | None, ties: Mapping[str, Tie], tree: int, size: int
) -> np.ndarray:
    """The coordinates a tree's designs are compared on (a box: all of them)."""
    if representation is None:
        return np.ones(size, dtype=bool)
    return used_slots(representation.spec_names, representation.structures[tree], ties)


def check_transfer_from(session: Session, *, trial_id: int, source_id: int) -> None:
    """A trial's ``transfer_from`` names what a lease could have offered it: another
    trial of its own study, which has ``task.transfer``, complete with a checkpoint a
    worker uploaded under the lease that completed it (InvalidError)."""
    study_id, task = session.execute(
        sa.select(TrialRow.study_id, StudyRow.task)
        .join(StudyRow, StudyRow.id == TrialRow.study_id)
        .where(TrialRow.id == trial_id)
    ).one()
    if (task or {}).get("transfer", "none") == "none":
        raise InvalidError(
            f"transfer_from: study {study_id} has no task.transfer, so its controllers "
            "start from nothing"
        )
    source = session.execute(
        sa.select(TrialRow.study_id, TrialRow.state, ArtifactRow.id.label("checkpoint"))
        .outerjoin(
            ArtifactRow,
            sa.and_(
                ArtifactRow.trial_id == TrialRow.id,
                ArtifactRow.name == CHECKPOINT_ARTIFACT,
                trusted_checkpoint(TrialRow.leases),
            ),
        )
        .where(TrialRow.id == source_id)
    ).one_or_none()
    if source_id == trial_id or source is None or source.study_id != study_id:
        raise InvalidError(
            f"transfer_from: trial {source_id} is not another trial of trial {trial_id}'s "
            "study (a controller starts only from its own study's designs)"
        )
    if source.state != TrialState.complete or source.checkpoint is None:
        raise InvalidError(
            f"transfer_from: trial {source_id} ({source.state}) is not a complete trial "
            f"with a {CHECKPOINT_ARTIFACT} a worker uploaded when it completed it: no "
            "controller starts from it"
        )


def record_transfer_from(session: Session, *, trial_id: int, source_id: int) -> None:
    """Keep where a trial's controller started as its ``info.transfer_from``."""
    check_transfer_from(session, trial_id=trial_id, source_id=source_id)
    row = session.get(TrialRow, trial_id)
    assert row is not None
    row.info = {**(row.info or {}), "transfer_from": source_id}
