"""Dependency aliases shared by the routers.

Dependencies that only read ``app.state`` are ``async def``: FastAPI runs a sync
dependency in its thread pool, and a hop there per dependency per request cost more
than the hot routes' own work."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Annotated

from fastapi import Depends, Path, Query, Request
from sqlalchemy.orm import Session

from adclient.ids import MAX_ID
from adclient.schemas import MAX_WORKER_PAGE
from adservice.artifacts import ArtifactStore
from adservice.auth import Principal, Role, require
from adservice.db import Database
from adservice.errors import InvalidError
from adservice.services.trials import Proposing
from adservice.settings import Settings


async def get_app_settings(request: Request) -> Settings:
    settings: Settings = request.app.state.settings
    return settings


async def get_database(request: Request) -> Database:
    db: Database = request.app.state.db
    return db


async def get_proposing(request: Request) -> Proposing:
    proposing: Proposing = request.app.state.proposing
    return proposing


async def get_artifact_store(request: Request) -> ArtifactStore:
    store: ArtifactStore = request.app.state.artifacts
    return store


def read_session(db: Annotated[Database, Depends(get_database)]) -> Iterator[Session]:
    """A read-only transaction; writes go through ``Database.write`` explicitly, so a
    commit always happens before the response is sent."""
    with db.read() as session:
        yield session


SettingsDep = Annotated[Settings, Depends(get_app_settings)]
DatabaseDep = Annotated[Database, Depends(get_database)]
ProposingDep = Annotated[Proposing, Depends(get_proposing)]
ArtifactStoreDep = Annotated[ArtifactStore, Depends(get_artifact_store)]
SessionDep = Annotated[Session, Depends(read_session)]


ReaderDep = Annotated[Principal, Depends(require(Role.reader))]
WorkerDep = Annotated[Principal, Depends(require(Role.worker))]
UserDep = Annotated[Principal, Depends(require(Role.user))]

StudyId = Annotated[int, Path(ge=1, le=MAX_ID, description="A study's id")]
TrialId = Annotated[int, Path(ge=1, le=MAX_ID, description="A trial's id")]
PageOffset = Annotated[int, Query(ge=0, le=MAX_ID, description="how many to skip")]
WorkerLimit = Annotated[
    int, Query(ge=1, le=MAX_WORKER_PAGE, description="the most workers to answer, newest first")
]


MAX_LISTED = 1000


def listed_numbers(text: str, what: str) -> list[int]:
    """A comma-separated list of integers in [0, MAX_ID], at most ``MAX_LISTED`` of them."""
    parts = [part for part in text.split(",") if part.strip()]
    if len(parts) > MAX_LISTED:
        raise InvalidError(f"{what}: at most {MAX_LISTED} numbers, got {len(parts)}")
    try:
        numbers = [int(part) for part in parts]
    except ValueError:
        raise InvalidError(f"{what}: expected comma-separated integers: {text[:40]!r}") from None
    if any(not 0 <= number <= MAX_ID for number in numbers):
        raise InvalidError(f"{what}: numbers must be between 0 and {MAX_ID}")
    return numbers
