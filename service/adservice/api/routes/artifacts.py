"""Artifacts of a trial (URDF, image, curves): upload whole, read back."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from fastapi import APIRouter, Header, Query, Request
from fastapi import Path as PathParam
from fastapi.responses import FileResponse
from starlette.concurrency import run_in_threadpool

from adclient.schemas import NAME_PATTERN, ArtifactInfo
from adservice.api.deps import (
    ArtifactStoreDep,
    DatabaseDep,
    ReaderDep,
    SessionDep,
    SettingsDep,
    TrialId,
    WorkerDep,
)
from adservice.artifacts import INERT_HEADERS, SNIFF_BYTES, served_type
from adservice.convert import artifact_schema
from adservice.db import Database
from adservice.errors import NotFoundError
from adservice.repository import artifacts as artifact_repo

router = APIRouter(prefix="/api/v1/trials/{trial_id}/artifacts", tags=["artifacts"])

ArtifactName = Annotated[str, PathParam(pattern=NAME_PATTERN, max_length=128)]


@router.get("")
def list_artifacts(trial_id: TrialId, session: SessionDep, _: ReaderDep) -> list[ArtifactInfo]:
    return [
        artifact_schema(row) for row in artifact_repo.list_artifacts(session, trial_id=trial_id)
    ]


@router.put("/{name}", status_code=201)
async def put_artifact(
    trial_id: TrialId,
    name: ArtifactName,
    request: Request,
    db: DatabaseDep,
    store: ArtifactStoreDep,
    settings: SettingsDep,
    caller: WorkerDep,
    content_type: Annotated[str, Header(max_length=128)] = "application/octet-stream",
    worker_id: Annotated[str | None, Query(min_length=1, max_length=128)] = None,
) -> ArtifactInfo:
    """Upload while holding the trial's lease (``worker_id`` names the holder), or, for a
    trial asked from a study without workers, as the study's owner; within the trial's
    quota and the owner's storage quota. The body is stored as it comes; the type it is
    served with is decided from its bytes when it is read back."""
    quota = artifact_repo.ArtifactQuota(
        count=settings.max_artifacts_per_trial,
        total_bytes=settings.max_trial_artifact_bytes,
        artifact_bytes=settings.max_artifact_bytes,
        owner_bytes=settings.owner_storage_bytes,
    )

    def room() -> tuple[int, artifact_repo.UploadRoom]:
        with db.write() as session:
            trial, left = artifact_repo.artifact_room(
                session,
                trial_id=trial_id,
                name=name,
                worker_id=worker_id,
                caller=caller,
                quota=quota,
            )
            return trial.study_id, left

    study_id, left = await run_in_threadpool(room)
    path, size, sha256 = await store.write(
        study_id=study_id,
        trial_id=trial_id,
        name=name,
        chunks=request.stream(),
        limit=left.bytes,
        limit_named=left.limit,
    )

    def record() -> tuple[ArtifactInfo, str | None]:
        with db.write() as session:
            row, replaced = artifact_repo.record_artifact(
                session,
                trial_id=trial_id,
                name=name,
                content_type=content_type,
                size=size,
                sha256=sha256,
                path=str(path),
                worker_id=worker_id,
                caller=caller,
                quota=quota,
            )
            return artifact_schema(row), replaced

    try:
        info, replaced = await run_in_threadpool(record)
    except BaseException:
        # Refused (lease lost, quota) or failed: the artifact stays as it was. The same
        # bytes uploaded again have the same name, which the stored row may point at.
        if not await run_in_threadpool(_recorded, db, trial_id, name, str(path)):
            store.discard(path)
        raise
    if replaced is not None:
        store.discard(replaced)
    return info


def _recorded(db: Database, trial_id: int, name: str, path: str) -> bool:
    with db.read() as session:
        return artifact_repo.artifact_path(session, trial_id=trial_id, name=name) == path


@router.get(
    "/{name}",
    response_class=FileResponse,
    responses={
        200: {
            "description": "The artifact's bytes: PNG, JPEG, GIF and WebP images inline, "
            "anything else as a download (application/json, text/plain, text/csv, "
            "application/xml or application/octet-stream), never a type a browser runs",
            "content": {"*/*": {"schema": {"type": "string", "format": "binary"}}},
        }
    },
)
def get_artifact(
    trial_id: TrialId, name: ArtifactName, session: SessionDep, _: ReaderDep
) -> FileResponse:
    row = artifact_repo.get_artifact(session, trial_id=trial_id, name=name)
    path = Path(row.path)
    if not path.is_file() or path.stat().st_size != row.size:
        raise NotFoundError(f"artifact {name!r} of trial {trial_id} is missing or incomplete")
    with path.open("rb") as handle:
        media_type, inline = served_type(handle.read(SNIFF_BYTES), row.content_type)
    return FileResponse(
        path,
        media_type=media_type,
        filename=name,
        content_disposition_type="inline" if inline else "attachment",
        headers=INERT_HEADERS,
    )
