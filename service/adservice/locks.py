"""Per-study proposal locks: two asks on one study never see the same pending set.

Inside one process a ``threading.Lock`` per study; on PostgreSQL also a session-level
advisory lock, so several ``adserver`` processes on one database take turns too. The
routes wait for a study's turn on the event loop first (``ProposalRunner``), so a
thread that takes these locks finds the process's own one free and waits, if at all,
only for another process.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager

import sqlalchemy as sa

from adservice.db import Database

ADVISORY_NAMESPACE = 0x4144  # "AD": keeps our advisory keys apart from other users'


class StudyLocks:
    def __init__(self) -> None:
        self._guard = threading.Lock()
        self._locks: dict[int, threading.Lock] = {}

    def _local(self, study_id: int) -> threading.Lock:
        with self._guard:
            return self._locks.setdefault(study_id, threading.Lock())

    @contextmanager
    def hold(self, db: Database, study_id: int) -> Iterator[None]:
        with self._local(study_id):
            if db.dialect != "postgresql":
                yield
                return
            with db.engine.connect() as connection:
                key = {"ns": ADVISORY_NAMESPACE, "id": study_id}
                connection.execute(sa.text("SELECT pg_advisory_lock(:ns, :id)"), key)
                connection.commit()
                try:
                    yield
                finally:
                    connection.execute(sa.text("SELECT pg_advisory_unlock(:ns, :id)"), key)
                    connection.commit()
