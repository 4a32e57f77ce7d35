"""A study's shared controller (``task.transfer: shared``): its current version, and
the lease holder advancing it with its trial's update."""

from __future__ import annotations

from fastapi import APIRouter

from adclient.schemas import SharedUpdate, SharedVersion
from adservice.api.deps import DatabaseDep, ReaderDep, StudyId, TrialId, WorkerDep
from adservice.services import transfer as transfer_service

router = APIRouter(prefix="/api/v1", tags=["shared controllers"])


@router.get("/studies/{study_id}/shared-controller")
def current(study_id: StudyId, db: DatabaseDep, _: ReaderDep) -> SharedVersion | None:
    """The study's current shared controller: its version and the trial whose artifact
    holds its weights; null before its first version (or in a study without
    ``task.transfer: shared``)."""
    return transfer_service.shared_version(db, study_id=study_id)


@router.post("/trials/{trial_id}/shared-controller")
def advance(
    trial_id: TrialId, body: SharedUpdate, db: DatabaseDep, caller: WorkerDep
) -> SharedVersion:
    """The lease holder makes the update it uploaded (the trial's shared-controller.npz)
    the study's next version, if the study is still at ``base_version``; 409 naming the
    current version otherwise (merge onto it and send again). A repeat once done answers
    the same version."""
    return transfer_service.advance_shared(db, trial_id=trial_id, body=body, caller=caller)
