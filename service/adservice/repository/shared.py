"""Repository of shared controllers (``task.transfer: shared``): each study's current
version, and advancing it by compare-and-set.

Same conventions as every module of :mod:`adservice.repository` (an open session,
keyword-only arguments, domain errors, rows out). A version is the ``SHARED_ARTIFACT``
a worker uploaded under the lease of the trial that made it; the pointer to it lives in
its own table, so advancing it takes no lock on the study's row (docs/worker.md, "A
shared controller").
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime

import sqlalchemy as sa
from sqlalchemy.dialects.postgresql import insert as postgresql_insert
from sqlalchemy.dialects.sqlite import insert as sqlite_insert
from sqlalchemy.orm import Session

from adclient.schemas import SHARED_ARTIFACT
from adservice.errors import ConflictError, InvalidError
from adservice.models import ArtifactRow, SharedControllerRow, utcnow
from adservice.principals import Principal
from adservice.repository._shared import made_version
from adservice.repository.artifacts import trusted_checkpoint
from adservice.repository.leases import held_trial
from adservice.repository.studies import get_study


class SharedVersionConflict(ConflictError):
    """The study's shared controller is no longer at the version an update was made
    from: the worker merges its update onto the current version and asks again."""


@dataclass(frozen=True)
class MadeVersion:
    """A version a trial made (the study's current one, or an earlier one)."""

    version: int
    trial_id: int
    updated_at: datetime | None = None


def current_shared(session: Session, *, study_id: int) -> SharedControllerRow | None:
    """The study's current shared controller, None before its first version."""
    return session.get(SharedControllerRow, study_id)


def advance_shared(
    session: Session,
    *,
    trial_id: int,
    worker_id: str,
    base_version: int | None,
    caller: Principal,
) -> MadeVersion:
    """Make the held trial's uploaded ``SHARED_ARTIFACT`` its study's next shared version,
    if the study is still at ``base_version`` (None: no version yet); records
    ``{"from": base_version, "version": new}`` as the trial's ``info.shared``.

    A trial makes at most one version: asked again once it made one (a retry whose
    answer was lost, a later attempt of the trial), it is answered that version, and its
    ``SHARED_ARTIFACT`` is not replaced any more (``made_version``). Refused: a lost
    lease (409), a study without ``task.transfer: shared`` (422), an update not uploaded by a worker
    under this lease (409), a study that moved on (:class:`SharedVersionConflict`, 409)."""
    trial = held_trial(session, trial_id=trial_id, worker_id=worker_id, caller=caller)
    study = get_study(session, study_id=trial.study_id)
    if (study.task or {}).get("transfer") != "shared":
        raise InvalidError(
            f"study {study.id} has no task.transfer: shared: it keeps no shared controller"
        )
    made = made_version(trial.info)
    if made is not None:
        return MadeVersion(version=made, trial_id=trial.id)
    uploaded = session.scalar(
        sa.select(ArtifactRow.id).where(
            ArtifactRow.trial_id == trial.id,
            ArtifactRow.name == SHARED_ARTIFACT,
            trusted_checkpoint(trial.leases),
        )
    )
    if uploaded is None:
        raise ConflictError(
            f"trial {trial.id} has no {SHARED_ARTIFACT} uploaded by its worker under its "
            "current lease: upload the update first"
        )
    now = utcnow()
    if base_version is None:
        advanced = _created(session, study_id=study.id, trial_id=trial.id, now=now)
    else:
        advanced = _moved(
            session, study_id=study.id, base_version=base_version, trial_id=trial.id, now=now
        )
    latest = session.get(SharedControllerRow, study.id, populate_existing=True)
    if advanced and latest is not None:
        trial.info = {
            **(trial.info or {}),
            "shared": {"from": base_version, "version": latest.version},
        }
        session.flush()
        return MadeVersion(
            version=latest.version, trial_id=latest.trial_id, updated_at=latest.updated_at
        )
    raise SharedVersionConflict(
        f"study {study.id}'s shared controller is at version "
        f"{latest.version if latest else 'none'}, not {base_version or 'none'}: merge the "
        "update onto that version and send it again"
    )


def _created(session: Session, *, study_id: int, trial_id: int, now: datetime) -> bool:
    """Insert the study's first version; False when another update inserted it first."""
    insert = postgresql_insert if session.get_bind().dialect.name == "postgresql" else sqlite_insert
    statement = (
        insert(SharedControllerRow)
        .values(study_id=study_id, version=1, trial_id=trial_id, updated_at=now)
        .on_conflict_do_nothing(index_elements=["study_id"])
        .returning(SharedControllerRow.version)
    )
    return session.execute(statement).first() is not None


def _moved(
    session: Session, *, study_id: int, base_version: int, trial_id: int, now: datetime
) -> bool:
    """Advance the study from ``base_version``; False when it is at another version."""
    statement = (
        sa.update(SharedControllerRow)
        .where(
            SharedControllerRow.study_id == study_id, SharedControllerRow.version == base_version
        )
        .values(version=base_version + 1, trial_id=trial_id, updated_at=now)
        .returning(SharedControllerRow.version)
        .execution_options(synchronize_session=False)
    )
    return session.execute(statement).first() is not None
