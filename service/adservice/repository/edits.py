"""Repository: deleting a study, and the user attributes of studies and trials.

Apart from the ask/tell path because neither runs per trial; the same conventions as
every module of :mod:`adservice.repository`: an open session, keyword-only arguments,
domain errors.
"""

from __future__ import annotations

from typing import Any

import sqlalchemy as sa
from sqlalchemy.orm import Session

from adclient.schemas import TrialState, bounded_user_attrs
from adservice.errors import ConflictError, ForbiddenError, InvalidError
from adservice.models import ArtifactRow, StudyRow, TrialReportRow, TrialRow, WorkerRow, utcnow
from adservice.principals import Principal, Role
from adservice.repository._shared import locking
from adservice.repository.leases import held_trial
from adservice.repository.studies import check_manager, get_study
from adservice.repository.trials import get_trial


def _leases(session: Session, *, study_id: int) -> list[tuple[int, str]]:
    """(trial id, worker) of each of the study's trials a worker holds, locked."""
    query = (
        sa.select(TrialRow.id, TrialRow.worker_id)
        .where(
            TrialRow.study_id == study_id,
            TrialRow.state == TrialState.running,
            TrialRow.worker_id.is_not(None),
        )
        .order_by(TrialRow.id)
    )
    if locking(session):
        query = query.with_for_update()
    return [(trial_id, str(worker)) for trial_id, worker in session.execute(query)]


def delete_study(session: Session, *, study_id: int, caller: Principal, force: bool) -> list[str]:
    """Remove a study with its trials, their reports and artifact rows; return the paths
    of the artifact files, for the caller to remove once this commits.

    Refused while workers hold leases on its trials, unless ``force``: then the leases go
    with the trials, and a holder's next heartbeat, report or tell is a 404."""
    if locking(session):
        # Trials before the study: the order a tell and the lease sweep lock them in, so
        # a delete and a tell never wait on each other. No worker leases a locked trial.
        session.execute(
            sa.select(TrialRow.id)
            .where(TrialRow.study_id == study_id)
            .order_by(TrialRow.id)
            .with_for_update()
        ).all()
    study = get_study(session, study_id=study_id, for_update=True)
    check_manager(study, caller)
    held = _leases(session, study_id=study_id)
    if held and not force:
        workers = ", ".join(sorted({repr(worker) for _, worker in held}))
        raise ConflictError(
            f"study {study_id} has {len(held)} trial(s) leased by worker(s) {workers}: "
            "stop the study and let them finish, or delete with force=true to cancel "
            "their leases"
        )
    trial_ids = sa.select(TrialRow.id).where(TrialRow.study_id == study_id).scalar_subquery()
    paths = list(
        session.scalars(sa.select(ArtifactRow.path).where(ArtifactRow.trial_id.in_(trial_ids)))
    )
    session.execute(
        sa.update(WorkerRow)
        .where(WorkerRow.current_trial_id.in_(trial_ids))
        .values(current_trial_id=None)
    )
    session.execute(sa.delete(ArtifactRow).where(ArtifactRow.trial_id.in_(trial_ids)))
    session.execute(sa.delete(TrialReportRow).where(TrialReportRow.study_id == study_id))
    session.execute(sa.delete(TrialRow).where(TrialRow.study_id == study_id))
    session.execute(sa.delete(StudyRow).where(StudyRow.id == study_id))
    return paths


def _merged(stored: dict[str, Any] | None, changes: dict[str, Any]) -> dict[str, Any]:
    """``stored`` with each key of ``changes`` set to its value, or deleted where the
    value is null; InvalidError when the result is over the limits."""
    merged = dict(stored or {})
    for key, value in changes.items():
        if value is None:
            merged.pop(key, None)
        else:
            merged[key] = value
    try:
        return bounded_user_attrs(merged, values=False)
    except ValueError as error:
        raise InvalidError(f"{error} (merged with the attributes stored)") from None


def set_study_user_attrs(
    session: Session, *, study_id: int, changes: dict[str, Any], caller: Principal
) -> StudyRow:
    """Merge ``changes`` into a study's user attributes: its owner's or an admin's."""
    study = get_study(session, study_id=study_id, for_update=True)
    check_manager(study, caller)
    study.user_attrs = _merged(study.user_attrs, changes)
    study.updated_at = utcnow()
    return study


def set_trial_user_attrs(
    session: Session,
    *,
    trial_id: int,
    changes: dict[str, Any],
    worker_id: str | None,
    caller: Principal,
) -> TrialRow:
    """Merge ``changes`` into a trial's user attributes: the study's owner or an admin
    at any time, or the worker holding its lease (naming itself) while it runs."""
    if worker_id is not None:
        trial = held_trial(session, trial_id=trial_id, worker_id=worker_id, caller=caller)
    else:
        trial = get_trial(session, trial_id=trial_id, for_update=True)
        if caller.role == Role.worker:
            raise ForbiddenError(
                "a worker token sets user attributes only on a trial it holds: give worker_id"
            )
        check_manager(get_study(session, study_id=trial.study_id), caller)
    trial.user_attrs = _merged(trial.user_attrs, changes)
    return trial
