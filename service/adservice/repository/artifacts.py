"""Repository of artifacts: the files a running trial uploads, within its quota, and
who uploaded each under which lease (what a worker may be given to load).

Same conventions as every module of :mod:`adservice.repository` (an open session,
keyword-only arguments, domain errors, rows out); the files themselves are the caller's
(``adservice.artifacts``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum

import sqlalchemy as sa
from sqlalchemy.orm import InstrumentedAttribute, Session

from adclient.schemas import SHARED_ARTIFACT, TrialState
from adservice.errors import ConflictError, NotFoundError, TooLargeError
from adservice.models import ArtifactRow, TrialRow, utcnow
from adservice.principals import Principal, Role
from adservice.repository import quotas as quota_repo
from adservice.repository._shared import made_version
from adservice.repository.leases import held_trial
from adservice.repository.studies import check_manager, get_study
from adservice.repository.trials import get_trial


class Uploader(StrEnum):
    """Who uploaded an artifact (``ArtifactRow.uploader``). Only a ``worker``'s file is
    ever handed to another job to load (docs/security.md, "What a worker trusts")."""

    worker = "worker"
    """The lease holder, with a worker or admin token (or any caller with auth off)."""
    user = "user"
    """The lease holder, with a user token: a user may lease jobs, not feed workers."""
    owner = "owner"
    """The study's owner, to a trial it asked (no worker, no lease)."""


def trusted_checkpoint(
    lease: sa.ColumnElement[int] | InstrumentedAttribute[int] | int,
) -> sa.ColumnElement[bool]:
    """The artifact row (joined or selected) is a checkpoint a worker may load: a
    worker uploaded it under the trial's lease numbered ``lease``. Rows stored before
    uploaders were recorded (uploader NULL) never are."""
    return sa.and_(ArtifactRow.uploader == Uploader.worker.value, ArtifactRow.attempt == lease)


def _uploader(trial: TrialRow, caller: Principal) -> Uploader:
    if trial.worker_id is None:
        return Uploader.owner
    return Uploader.user if caller.role == Role.user else Uploader.worker


_NAMED = ArtifactRow.name == sa.bindparam("name")
_TRIAL_ARTIFACTS = sa.select(
    sa.func.count().filter(~_NAMED),
    sa.func.coalesce(sa.func.sum(ArtifactRow.size).filter(~_NAMED), 0),
    sa.func.coalesce(sa.func.sum(ArtifactRow.size).filter(_NAMED), 0),
).where(ArtifactRow.trial_id == sa.bindparam("trial_id"))
"""A trial's other artifacts (their count and bytes) and the bytes of the one named
``name`` (which an upload replaces); built once, as every upload runs it twice."""


@dataclass(frozen=True)
class ArtifactQuota:
    count: int
    """Artifacts one trial may have (``AD_MAX_ARTIFACTS_PER_TRIAL``)."""
    total_bytes: int
    """Bytes all of one trial's artifacts may take (``AD_MAX_TRIAL_ARTIFACT_BYTES``)."""
    artifact_bytes: int
    """Bytes one artifact may take (``AD_MAX_ARTIFACT_BYTES``)."""
    owner_bytes: int | None = None
    """Bytes all of one owner's studies may store, artifacts and URDFs together
    (``AD_OWNER_STORAGE_BYTES``); None: no quota."""


@dataclass(frozen=True)
class UploadRoom:
    """How many bytes an upload may write, and the limit that sets it."""

    bytes: int
    limit: str
    """The limit, its size and its setting, as a refusal names it."""


def artifact_room(
    session: Session,
    *,
    trial_id: int,
    name: str,
    worker_id: str | None,
    caller: Principal,
    quota: ArtifactQuota,
    for_update: bool = False,
) -> tuple[TrialRow, UploadRoom]:
    """The trial an upload may write to, and how many bytes it may write: only while the
    trial runs, by its lease holder (or, for an asked trial, the study's owner), within
    the size of one artifact, the trial's quota and its owner's storage quota (``name``'s
    present file, which it would replace, not counted). ``for_update`` locks the owner's
    storage total too, so that the room stays the room until the commit."""
    trial = get_trial(session, trial_id=trial_id, for_update=True)
    if trial.state != TrialState.running:
        raise ConflictError(
            f"trial {trial_id} is {trial.state}: artifacts are uploaded while it runs"
        )
    if trial.worker_id is None:
        check_manager(get_study(session, study_id=trial.study_id), caller)
    else:
        held_trial(session, trial_id=trial_id, worker_id=worker_id, caller=caller)
    made = made_version(trial.info) if name == SHARED_ARTIFACT else None
    if made is not None:
        raise ConflictError(
            f"trial {trial_id} made version {made} of its study's shared controller: its "
            f"{SHARED_ARTIFACT} is that version and is not replaced"
        )
    count, others, present = (
        session.connection().execute(_TRIAL_ARTIFACTS, {"trial_id": trial_id, "name": name}).one()
    )
    if count >= quota.count:
        raise TooLargeError(
            f"trial {trial_id} already has {count} artifacts, the most one trial may have "
            "(AD_MAX_ARTIFACTS_PER_TRIAL)"
        )
    rooms: list[tuple[int, Callable[[], str]]] = [
        (
            quota.artifact_bytes,
            lambda: (
                f"the limit of {quota.artifact_bytes} bytes per artifact (AD_MAX_ARTIFACT_BYTES)"
            ),
        ),
        (
            quota.total_bytes - int(others),
            lambda: (
                f"the {quota.total_bytes} bytes one trial's artifacts may take "
                f"(AD_MAX_TRIAL_ARTIFACT_BYTES): its others take {others}"
            ),
        ),
    ]
    if quota.owner_bytes is not None:
        owner_bytes = quota.owner_bytes
        stored = quota_repo.owner_storage(session, study_id=trial.study_id, for_update=for_update)
        rooms.append(
            (owner_bytes - (stored.used - int(present)), lambda: stored.of(session, owner_bytes))
        )
    left, named = min(rooms, key=lambda each: each[0])
    room = UploadRoom(left, named())
    if room.bytes <= 0:
        raise TooLargeError(f"trial {trial_id} takes no more artifacts: {room.limit}")
    return trial, room


def record_artifact(
    session: Session,
    *,
    trial_id: int,
    name: str,
    content_type: str,
    size: int,
    sha256: str,
    path: str,
    worker_id: str | None,
    caller: Principal,
    quota: ArtifactQuota,
) -> tuple[ArtifactRow, str | None]:
    """Record an artifact whose file is already complete on disk (last step of a PUT),
    checking again that the lease and the quotas still allow it, with who uploaded it
    under which lease; also returns the path of the file it replaces, if any (the caller
    removes it after the commit)."""
    trial, room = artifact_room(
        session,
        trial_id=trial_id,
        name=name,
        worker_id=worker_id,
        caller=caller,
        quota=quota,
        for_update=True,
    )
    if size > room.bytes:
        raise TooLargeError(f"artifact {name!r} of {size} bytes exceeds {room.limit}")
    row = session.scalars(
        sa.select(ArtifactRow).where(ArtifactRow.trial_id == trial_id, ArtifactRow.name == name)
    ).one_or_none()
    replaced = row.path if row is not None and row.path != path else None
    if row is None:
        row = ArtifactRow(trial_id=trial_id, name=name)
        session.add(row)
    row.content_type = content_type
    row.size = size
    row.sha256 = sha256
    row.path = path
    row.created_at = utcnow()
    row.uploader = _uploader(trial, caller).value
    row.attempt = None if row.uploader == Uploader.owner else trial.leases
    session.flush()
    return row, replaced


def artifact_path(session: Session, *, trial_id: int, name: str) -> str | None:
    """Where the stored artifact ``name`` of a trial lives, if there is one."""
    return session.scalar(
        sa.select(ArtifactRow.path).where(
            ArtifactRow.trial_id == trial_id, ArtifactRow.name == name
        )
    )


def get_artifact(session: Session, *, trial_id: int, name: str) -> ArtifactRow:
    row = session.scalars(
        sa.select(ArtifactRow).where(ArtifactRow.trial_id == trial_id, ArtifactRow.name == name)
    ).one_or_none()
    if row is None:
        get_trial(session, trial_id=trial_id)
        raise NotFoundError(f"trial {trial_id} has no artifact {name!r}")
    return row


def list_artifacts(session: Session, *, trial_id: int) -> list[ArtifactRow]:
    get_trial(session, trial_id=trial_id)
    return list(
        session.scalars(
            sa.select(ArtifactRow)
            .where(ArtifactRow.trial_id == trial_id)
            .order_by(ArtifactRow.name)
        )
    )
