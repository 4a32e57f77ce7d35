"""Trials: read, tell, heartbeat, release, user attributes, and a trial's robot: its
URDF and where the simulator starts it."""

from __future__ import annotations

from fastapi import APIRouter, Response

from adclient.schemas import (
    HeartbeatRequest,
    HeartbeatResponse,
    ReleaseRequest,
    Spawn,
    TellRequest,
    Trial,
    TrialUpdate,
)
from adservice import robots
from adservice.api.deps import (
    DatabaseDep,
    ProposingDep,
    ReaderDep,
    SessionDep,
    SettingsDep,
    TrialId,
    WorkerDep,
)
from adservice.api.responses import model_response
from adservice.auth import Role
from adservice.convert import trial_schema
from adservice.errors import ForbiddenError
from adservice.repository import edits as edit_repo
from adservice.repository import leases as lease_repo
from adservice.repository import studies as study_repo
from adservice.repository import tell as tell_repo
from adservice.repository import trials as trial_repo

router = APIRouter(prefix="/api/v1/trials", tags=["trials"])


@router.get("/{trial_id}")
def get_trial(trial_id: TrialId, session: SessionDep, _: ReaderDep) -> Trial:
    return trial_schema(trial_repo.get_trial(session, trial_id=trial_id))


@router.patch("/{trial_id}")
def update_trial(trial_id: TrialId, body: TrialUpdate, db: DatabaseDep, caller: WorkerDep) -> Trial:
    """Set user attributes (a null value deletes its key): the study's owner or an admin,
    or the worker holding the trial's lease, naming itself in ``worker_id``."""
    with db.write() as session:
        return trial_schema(
            edit_repo.set_trial_user_attrs(
                session,
                trial_id=trial_id,
                changes=body.user_attrs,
                worker_id=body.worker_id,
                caller=caller,
            )
        )


@router.post("/{trial_id}/tell", response_model=Trial)
async def tell(
    trial_id: TrialId, body: TellRequest, proposing: ProposingDep, caller: WorkerDep
) -> Response:
    if caller.role == Role.worker and body.worker_id is None:
        raise ForbiddenError("a worker token tells only the trials it holds: give worker_id")
    db = proposing.db

    def write() -> Trial:
        with db.write() as session:
            trial = tell_repo.tell_trial(
                session,
                trial_id=trial_id,
                body=body,
                caller=caller,
                cached_outcomes=proposing.configs.cached_outcomes,
            )
        if db.dialect == "postgresql":  # see tell_trial: the study's end, after the commit
            with db.write() as session:
                study_repo.finish_if_done(session, study_id=trial.study_id)
        return trial

    return model_response(await db.run(write))


@router.post("/{trial_id}/heartbeat")
def heartbeat(
    trial_id: TrialId,
    body: HeartbeatRequest,
    db: DatabaseDep,
    settings: SettingsDep,
    caller: WorkerDep,
) -> HeartbeatResponse:
    with db.write() as session:
        row = lease_repo.heartbeat(
            session,
            trial_id=trial_id,
            worker_id=body.worker_id,
            lease_seconds=settings.lease_seconds,
            caller=caller,
        )
    assert row.lease_expires_at is not None
    return HeartbeatResponse(trial_id=row.id, lease_expires_at=row.lease_expires_at)


@router.post("/{trial_id}/release")
def release(trial_id: TrialId, body: ReleaseRequest, db: DatabaseDep, caller: WorkerDep) -> Trial:
    """The lease holder gives the trial back to the queue (409 if it does not hold it, 403
    for another token); an admin may name no worker."""
    with db.write() as session:
        return trial_schema(
            lease_repo.release_lease(
                session, trial_id=trial_id, worker_id=body.worker_id, caller=caller
            )
        )


@router.get("/{trial_id}/urdf", response_class=Response)
async def trial_urdf(trial_id: TrialId, proposing: ProposingDep, _: ReaderDep) -> Response:
    """The trial's robot as URDF: a design study's written from its design, a template
    study's as expanded once when its params were fixed (422 naming the template's
    message where they do not expand; 503 while the expansion queue is full, for a
    trial stored before the server kept URDFs)."""
    urdf = await robots.trial_urdf(proposing.db, proposing.expansions, trial_id=trial_id)
    return Response(
        urdf,
        media_type="application/xml",
        headers={"Content-Disposition": f'attachment; filename="trial-{trial_id}.urdf"'},
    )


@router.get("/{trial_id}/spawn")
async def trial_spawn(trial_id: TrialId, proposing: ProposingDep, _: ReaderDep) -> Spawn:
    """Where adworker's simulator starts the trial's robot before every episode: its root
    frame's pose and its joints' positions (``adclient.spawn``), as the worker computes
    them. 422 for a box study's trial, or a study with no task or an external one."""
    return await robots.trial_spawn(proposing.db, proposing.expansions, trial_id=trial_id)
