"""Repository of controller transfer (``task.transfer: nearest``): which evaluated
design a job's controller starts from, and recording where a trial started.

Same conventions as every module of :mod:`adservice.repository` (an open session,
keyword-only arguments, domain errors). A source is a finished trial of the same study
whose checkpoint artifact was uploaded, of the same tree as the job's design (so the
same observation and action spaces), among the ``transfer_among`` best of that tree; of
those, the nearest by the normalised spec distance. The choice runs when a job is
leased, never on the ask/tell hot path of a study without transfer.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import sqlalchemy as sa
from sqlalchemy.orm import Session

from adclient.decode import spec_vector, used_slots
from adclient.designs import Representation
from adclient.pruning import CHECKPOINT_ARTIFACT
from adclient.schemas import TaskConfig, TransferSource, Trial, TrialState
from adclient.ties import Tie
from adservice.errors import InvalidError
from adservice.models import ArtifactRow, TrialRow

SCANNED_SOURCES = 2000
"""The most finished trials with a checkpoint a lease looks through (the best first)."""


def transfer_source(
    session: Session,
    *,
    trial: Trial,
    task: TaskConfig,
    representation: Representation | None,
    ties: Mapping[str, Tie],
    bounds: np.ndarray,
    maximize: bool,
) -> TransferSource | None:
    """Where ``trial``'s controller starts, or None (transfer off, a trial resuming
    from its own checkpoint, or no evaluated design of its tree with a checkpoint)."""
    if task.transfer == "none" or trial.checkpoint is not None:
        return None
    order = TrialRow.value.desc() if maximize else TrialRow.value.asc()
    rows = session.execute(
        sa.select(TrialRow.id, TrialRow.vector)
        .join(ArtifactRow, ArtifactRow.trial_id == TrialRow.id)
        .where(
            TrialRow.study_id == trial.study_id,
            TrialRow.id != trial.id,
            TrialRow.state == TrialState.complete.value,
            TrialRow.value.is_not(None),
            ArtifactRow.name == CHECKPOINT_ARTIFACT,
        )
        .order_by(order, TrialRow.id)
        .limit(SCANNED_SOURCES)
    ).all()
    tree, specs, used = _key(representation, ties, bounds, trial.vector)
    best: list[tuple[int, np.ndarray]] = []
    for row in rows:
        other_tree, other_specs, _ = _key(representation, ties, bounds, row.vector)
        if other_tree == tree:
            best.append((row.id, other_specs))
            if len(best) == task.transfer_among:
                break
    if not best:
        return None
    distances = [
        float(np.sqrt(np.mean((other[used] - specs[used]) ** 2))) if used.any() else 0.0
        for _, other in best
    ]
    nearest = int(np.argmin(distances))
    return TransferSource(
        trial_id=best[nearest][0], artifact=CHECKPOINT_ARTIFACT, distance=distances[nearest]
    )


def _key(
    representation: Representation | None,
    ties: Mapping[str, Tie],
    bounds: np.ndarray,
    vector: Sequence[float],
) -> tuple[int, np.ndarray, np.ndarray]:
    """(tree, coordinates in [0, 1], the tree's coordinates) of a trial's vector."""
    if representation is None:
        low, high = bounds
        span = np.where(high > low, high - low, 1.0)
        values = np.clip((np.asarray(vector, dtype=np.float64) - low) / span, 0.0, 1.0)
        return 0, values, np.ones(len(values), dtype=bool)
    structure, specs = spec_vector(representation, vector)
    return (
        structure,
        specs,
        used_slots(representation.spec_names, representation.structures[structure], ties),
    )


def check_transfer_from(session: Session, *, trial_id: int, source_id: int) -> None:
    """A trial's ``transfer_from`` names another trial of its own study (InvalidError)."""
    study_of = dict(
        session.execute(
            sa.select(TrialRow.id, TrialRow.study_id).where(TrialRow.id.in_([trial_id, source_id]))
        ).all()
    )
    if source_id == trial_id or study_of.get(source_id) != study_of.get(trial_id):
        raise InvalidError(
            f"transfer_from: trial {source_id} is not another trial of trial {trial_id}'s "
            "study (a controller starts only from its own study's designs)"
        )


def record_transfer_from(session: Session, *, trial_id: int, source_id: int) -> None:
    """Keep where a trial's controller started as its ``info.transfer_from``."""
    check_transfer_from(session, trial_id=trial_id, source_id=source_id)
    row = session.get(TrialRow, trial_id)
    assert row is not None
    row.info = {**(row.info or {}), "transfer_from": source_id}
