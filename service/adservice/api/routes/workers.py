"""The workers this server has seen, newest first: which tasks each serves and when it
last leased or reported, so a study that no worker serves can say so."""

from __future__ import annotations

from fastapi import APIRouter

from adclient.schemas import MAX_WORKER_PAGE, WorkerInfo
from adservice.api.deps import PageOffset, ReaderDep, SessionDep, WorkerLimit
from adservice.convert import worker_schema
from adservice.repository import leases as lease_repo

router = APIRouter(prefix="/api/v1/workers", tags=["workers"])


@router.get("")
def list_workers(
    session: SessionDep,
    _: ReaderDep,
    offset: PageOffset = 0,
    limit: WorkerLimit = MAX_WORKER_PAGE,
) -> list[WorkerInfo]:
    rows = lease_repo.list_workers(session, offset=offset, limit=limit)
    return [worker_schema(row) for row in rows]
