"""Jobs: workers lease trials of managed studies."""

from __future__ import annotations

from fastapi import APIRouter, Response

from adclient.schemas import Job, LeaseRequest
from adservice.api.deps import ProposingDep, SettingsDep, WorkerDep
from adservice.services.jobs import lease_job

router = APIRouter(prefix="/api/v1/jobs", tags=["jobs"])


@router.post("/lease", response_model=Job, responses={204: {"description": "No work now"}})
async def lease(
    body: LeaseRequest,
    proposing: ProposingDep,
    settings: SettingsDep,
    caller: WorkerDep,
) -> Response | Job:
    job = await lease_job(
        proposing,
        worker_id=body.worker_id,
        caller=caller,
        lease_seconds=settings.lease_seconds,
        tasks=body.tasks,
        learners=body.learners,
    )
    if job is None:
        return Response(status_code=204)
    return job
