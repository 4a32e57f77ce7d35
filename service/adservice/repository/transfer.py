"""Repository of controller transfer (``task.transfer: nearest``): the rows of the
candidate sources a job's controller may start from, the checks of a trial's
``transfer_from`` that need the database, and its one writer.

Same conventions as every module of :mod:`adservice.repository` (an open session,
keyword-only arguments, domain errors). A candidate is a complete trial of the same
study whose checkpoint artifact a worker uploaded under the lease that completed it
(never an owner's or a user token's upload, nor an earlier lease's: see
:func:`adservice.repository.artifacts.trusted_checkpoint`) and feasible under the
study's constraints. Which of them a job starts from (its tree, the best, the nearest)
is :mod:`adservice.services.transfer`'s choice.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from typing import Any, NamedTuple

import sqlalchemy as sa
from sqlalchemy.orm import Session

from adclient.objectives import Outcomes
from adclient.pruning import CHECKPOINT_ARTIFACT
from adclient.schemas import Trial, TrialState
from adservice.errors import InvalidError
from adservice.models import ArtifactRow, StudyRow, TrialRow
from adservice.repository.artifacts import trusted_checkpoint

SCANNED_SOURCES = 2000
"""The most finished trials with a checkpoint a lease looks through (for one objective
the best first, for several the newest first)."""


class SourceRow(NamedTuple):
    """A candidate source: a trial's id, its vector and (several objectives) its values."""

    id: int
    vector: Sequence[float]
    values: Sequence[float | None] | None = None


def source_rows(session: Session, *, trial: Trial, outcomes: Outcomes) -> Iterator[SourceRow]:
    """The candidate sources of ``trial``'s controller, at most :data:`SCANNED_SOURCES`,
    read as they are iterated: for one objective the best first (ties by id), for
    several the newest first with their ``values``."""
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
    for row in session.execute(query):
        yield SourceRow(row.id, row.vector, row.values if outcomes.multi else None)


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


def record_transfer_from(session: Session, *, trial_id: int, source_id: int) -> dict[str, Any]:
    """Keep where a trial's controller started as its ``info.transfer_from`` (the one
    writer of it: a tell's and a pause's), after :func:`check_transfer_from`; returns the
    trial's info as it now is."""
    check_transfer_from(session, trial_id=trial_id, source_id=source_id)
    row = session.get(TrialRow, trial_id)
    assert row is not None
    row.info = {**(row.info or {}), "transfer_from": source_id}
    return row.info
