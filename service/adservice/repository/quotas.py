"""Repository of storage per owner: the bytes an owner's studies store (their trials'
artifacts and template URDFs), read from the running totals the database keeps
(``StudyStorageRow``, ``OwnerStorageRow``: triggers of migration 0015), and the quota
``AD_OWNER_STORAGE_BYTES`` checked where bytes are added.

Every read here is one indexed statement whatever the number of artifacts or URDFs.
Same conventions as every module of :mod:`adservice.repository`.
"""

from __future__ import annotations

from dataclasses import dataclass

import sqlalchemy as sa
from sqlalchemy.orm import Session

from adservice.errors import OverQuotaError
from adservice.models import OwnerStorageRow, StudyRow, StudyStorageRow
from adservice.repository._shared import locking

QUOTA_SETTING = "AD_OWNER_STORAGE_BYTES"
NO_OWNER = 0
"""The owner key of the studies without an owner (made with auth off): one owner."""


_OWNER_BYTES = (
    sa.select(OwnerStorageRow.owner_key, OwnerStorageRow.bytes)
    .join(StudyStorageRow, StudyStorageRow.owner_key == OwnerStorageRow.owner_key)
    .where(StudyStorageRow.study_id == sa.bindparam("study_id"))
)
"""Built once: an upload runs it twice, and building it cost three times running it."""
_LOCKED_STUDY_BYTES = (
    sa.select(StudyStorageRow.study_id)
    .where(StudyStorageRow.study_id == sa.bindparam("study_id"))
    .with_for_update()
)
_LOCKED_OWNER_BYTES = _OWNER_BYTES.with_for_update(of=OwnerStorageRow)


@dataclass(frozen=True)
class OwnerStorage:
    """What the owner of one study stores."""

    study_id: int
    owner_key: int
    used: int
    """Bytes of artifacts and URDFs all of the owner's studies store."""

    def of(self, session: Session, quota: int) -> str:
        """The quota, its setting and what is used of it, as a refusal names them."""
        return (
            f"the quota of {quota} bytes per owner ({QUOTA_SETTING}): "
            f"{self._whose(session)} store {self.used} bytes of artifacts and URDFs"
        )

    def over(self, session: Session, quota: int) -> str:
        """Why nothing more is stored for the owner (``used`` is ``quota`` or more)."""
        return f"{self.of(session, quota)}, the whole quota: delete studies to make room"

    def _whose(self, session: Session) -> str:
        if self.owner_key == NO_OWNER:
            return "the studies without an owner"
        name = session.scalar(sa.select(StudyRow.created_by).where(StudyRow.id == self.study_id))
        return (
            f"the studies of token {name!r}" if name else f"the studies of token {self.owner_key}"
        )


def owner_storage(session: Session, *, study_id: int, for_update: bool = False) -> OwnerStorage:
    """What the owner of ``study_id`` stores. ``for_update`` locks the study's and the
    owner's totals (on PostgreSQL, in that order, the order the triggers take them), so a
    check and the write it allows are one step for that owner."""
    connection = session.connection()
    statement = _OWNER_BYTES
    if for_update and locking(session):
        connection.execute(_LOCKED_STUDY_BYTES, {"study_id": study_id}).all()
        statement = _LOCKED_OWNER_BYTES
    row = connection.execute(statement, {"study_id": study_id}).one_or_none()
    if row is None:  # a study gone meanwhile stores nothing
        return OwnerStorage(study_id=study_id, owner_key=NO_OWNER, used=0)
    return OwnerStorage(study_id=study_id, owner_key=row.owner_key, used=int(row.bytes))


def check_room(session: Session, *, study_id: int, quota: int | None) -> None:
    """Refuse (OverQuotaError naming the quota and what is used) anything new stored for
    ``study_id`` once its owner stores ``quota`` bytes or more; None: no quota."""
    if quota is None:
        return
    stored = owner_storage(session, study_id=study_id)
    if stored.used >= quota:
        raise OverQuotaError(f"study {study_id} makes no new trials: {stored.over(session, quota)}")


QUOTA_PARAM = "storage_quota"
_WITHIN_QUOTA = sa.func.coalesce(StudyRow.owner_token_id, NO_OWNER).not_in(
    sa.select(OwnerStorageRow.owner_key).where(
        OwnerStorageRow.bytes >= sa.bindparam(QUOTA_PARAM, type_=sa.BigInteger)
    )
)


def within_quota(quota: int | None) -> tuple[list[sa.ColumnElement[bool]], dict[str, int]]:
    """Where-clauses on ``StudyRow`` for studies whose owner stores less than ``quota``
    bytes, and the parameters to execute them with (none of either for no quota). The
    owners at or past it are one scan of the small ``owner_storage`` table, read once per
    statement; the clause is built once, the quota given at execution."""
    if quota is None:
        return [], {}
    return [_WITHIN_QUOTA], {QUOTA_PARAM: quota}


def study_urdf_bytes(session: Session, *, study_id: int) -> int:
    """The bytes of the URDFs (and expansion errors) a study's trials store."""
    stored = session.scalar(
        sa.select(StudyStorageRow.urdf_bytes).where(StudyStorageRow.study_id == study_id)
    )
    return int(stored or 0)
