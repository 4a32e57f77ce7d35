"""Artifacts of a trial (URDF, image, curves): upload whole, read back."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from fastapi import APIRouter, Header, Request
from fastapi import Path as PathParam
from fastapi.responses import FileResponse
from starlette.concurrency import run_in_threadpool

from adclient.schemas import NAME_PATTERN, ArtifactInfo
from adservice import repository
from adservice.api.deps import (
    ArtifactStoreDep,
    DatabaseDep,
    ReaderDep,
    SessionDep,
    SettingsDep,
    TrialId,
    WorkerDep,
)
from adservice.convert import artifact_schema
from adservice.db import Database
from adservice.errors import NotFoundError
from adservice.models import TrialRow

router = APIRouter(prefix="/api/v1/trials/{trial_id}/artifacts", tags=["artifacts"])

ArtifactName = Annotated[str, PathParam(pattern=NAME_PATTERN, max_length=128)]


@router.get("")
def list_artifacts(trial_id: TrialId, session: SessionDep, _: ReaderDep) -> list[ArtifactInfo]:
    return [artifact_schema(row) for row in repository.list_artifacts(session, trial_id=trial_id)]


@router.put("/{name}", status_code=201)
async def put_artifact(
    trial_id: TrialId,
    name: ArtifactName,
    request: Request,
    db: DatabaseDep,
    store: ArtifactStoreDep,
    settings: SettingsDep,
    _: WorkerDep,
    content_type: Annotated[str, Header(max_length=128)] = "application/octet-stream",
) -> ArtifactInfo:
    trial = await run_in_threadpool(_trial, db, trial_id)
    path, size, sha256 = await store.write(
        study_id=trial.study_id,
        trial_id=trial_id,
        name=name,
        chunks=request.stream(),
        limit=settings.max_artifact_bytes,
    )
    return await run_in_threadpool(
        _record, db, trial_id, name, content_type, size, sha256, str(path)
    )


def _trial(db: Database, trial_id: TrialId) -> TrialRow:
    with db.read() as session:
        return repository.get_trial(session, trial_id=trial_id)


def _record(
    db: Database, trial_id: TrialId, name: str, content_type: str, size: int, sha256: str, path: str
) -> ArtifactInfo:
    with db.write() as session:
        row = repository.record_artifact(
            session,
            trial_id=trial_id,
            name=name,
            content_type=content_type,
            size=size,
            sha256=sha256,
            path=path,
        )
        return artifact_schema(row)


@router.get(
    "/{name}",
    response_class=FileResponse,
    responses={
        200: {
            "description": "The artifact's bytes, with the content type it was uploaded with",
            "content": {"*/*": {"schema": {"type": "string", "format": "binary"}}},
        }
    },
)
def get_artifact(
    trial_id: TrialId, name: ArtifactName, session: SessionDep, _: ReaderDep
) -> FileResponse:
    row = repository.get_artifact(session, trial_id=trial_id, name=name)
    path = Path(row.path)
    if not path.is_file() or path.stat().st_size != row.size:
        raise NotFoundError(f"artifact {name!r} of trial {trial_id} is missing or incomplete")
    return FileResponse(path, media_type=row.content_type)
