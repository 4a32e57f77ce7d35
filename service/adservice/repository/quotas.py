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


@dataclass(frozen=True)
class OwnerStorage:
    """What the owner of one study stores."""

    owner_key: int
    owner_name: str | None
    """The creating token's name (``StudyRow.created_by``)."""
    used: int
    """Bytes of artifacts and URDFs all of the owner's studies store."""

    @property
    def whose(self) -> str:
        if self.owner_key == NO_OWNER:
            return "the studies without an owner"
        name = repr(self.owner_name) if self.owner_name else str(self.owner_key)
        return f"the studies of token {name}"

    def of(self, quota: int) -> str:
        """The quota, its setting and what is used of it, as a refusal names them."""
        return (
            f"the quota of {quota} bytes per owner ({QUOTA_SETTING}): {self.whose} "
            f"store {self.used} bytes of artifacts and URDFs"
        )

    def over(self, quota: int) -> str:
        """Why nothing more is stored for the owner (``used`` is ``quota`` or more)."""
        return f"{self.of(quota)}, the whole quota: delete studies to make room"


def owner_storage(session: Session, *, study_id: int, for_update: bool = False) -> OwnerStorage:
    """What the owner of ``study_id`` stores. ``for_update`` locks the study's and the
    owner's totals (on PostgreSQL, in that order, the order the triggers take them), so a
    check and the write it allows are one step for that owner."""
    if for_update and locking(session):
        session.execute(
            sa.select(StudyStorageRow.study_id)
            .where(StudyStorageRow.study_id == study_id)
            .with_for_update()
        ).all()
    query = (
        sa.select(StudyStorageRow.owner_key, StudyRow.created_by, OwnerStorageRow.bytes)
        .join(StudyRow, StudyRow.id == StudyStorageRow.study_id)
        .join(OwnerStorageRow, OwnerStorageRow.owner_key == StudyStorageRow.owner_key)
        .where(StudyStorageRow.study_id == study_id)
    )
    if for_update and locking(session):
        query = query.with_for_update(of=OwnerStorageRow)
    row = session.execute(query).one_or_none()
    if row is None:  # a study gone meanwhile stores nothing
        return OwnerStorage(owner_key=NO_OWNER, owner_name=None, used=0)
    return OwnerStorage(owner_key=row.owner_key, owner_name=row.created_by, used=int(row.bytes))


def check_room(session: Session, *, study_id: int, quota: int | None) -> None:
    """Refuse (OverQuotaError naming the quota and what is used) anything new stored for
    ``study_id`` once its owner stores ``quota`` bytes or more; None: no quota."""
    if quota is None:
        return
    stored = owner_storage(session, study_id=study_id)
    if stored.used >= quota:
        raise OverQuotaError(f"study {study_id} makes no new trials: {stored.over(quota)}")


def within_quota(quota: int | None) -> list[sa.ColumnElement[bool]]:
    """Where-clauses on ``StudyRow``: studies whose owner stores less than ``quota``
    bytes (none for no quota). The owners at or past it are one scan of the small
    ``owner_storage`` table, read once per statement."""
    if quota is None:
        return []
    full = sa.select(OwnerStorageRow.owner_key).where(OwnerStorageRow.bytes >= quota)
    return [sa.func.coalesce(StudyRow.owner_token_id, NO_OWNER).not_in(full)]


def study_urdf_bytes(session: Session, *, study_id: int) -> int:
    """The bytes of the URDFs (and expansion errors) a study's trials store."""
    stored = session.scalar(
        sa.select(StudyStorageRow.urdf_bytes).where(StudyStorageRow.study_id == study_id)
    )
    return int(stored or 0)
