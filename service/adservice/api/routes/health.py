"""Liveness: the process answers and its database does."""

from __future__ import annotations

import sqlalchemy as sa
from fastapi import APIRouter

from adservice.api.deps import SessionDep

router = APIRouter(tags=["health"])


@router.get("/healthz")
def healthz(session: SessionDep) -> dict[str, str]:
    session.execute(sa.text("SELECT 1"))
    return {"status": "ok"}
