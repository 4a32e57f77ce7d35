"""Intermediate reports of a running trial, the curve a trial reported, and pausing a
trial at an ASHA rung."""

from __future__ import annotations

from fastapi import APIRouter

from adclient.pruning import PauseRequest, ReportRequest, ReportResponse, TrialReport
from adclient.schemas import Trial
from adservice.api.deps import DatabaseDep, ReaderDep, SessionDep, TrialId, WorkerDep
from adservice.repository import reports as report_repo
from adservice.services import reports as report_service

router = APIRouter(prefix="/api/v1/trials", tags=["reports"])


@router.post("/{trial_id}/report")
def report(
    trial_id: TrialId, body: ReportRequest, db: DatabaseDep, caller: WorkerDep
) -> ReportResponse:
    """Record the trial's value at ``step``; ``should_stop`` says whether the study's
    pruner would stop it there (then tell it ``{"state": "pruned"}``). Repeating a report
    is harmless; a finished trial or a lost lease is 409; another token's trial 403."""
    return report_service.report(db, trial_id=trial_id, body=body, caller=caller)


@router.get("/{trial_id}/reports")
def reports(trial_id: TrialId, session: SessionDep, _: ReaderDep) -> list[TrialReport]:
    """The trial's reported curve, in order of step."""
    rows = report_repo.trial_reports(session, trial_id=trial_id)
    return [TrialReport(step=row.step, value=row.value, created_at=row.created_at) for row in rows]


@router.post("/{trial_id}/pause")
def pause(trial_id: TrialId, body: PauseRequest, db: DatabaseDep, caller: WorkerDep) -> Trial:
    """The lease holder pauses its trial at ``step`` with the checkpoint artifact it
    uploaded (a report answered ``pause``); the trial waits at its ASHA rung until it is
    promoted (queued again) or the study's budget is spent (pruned). A repeat is
    harmless; a lost lease, a study that does not pause or a missing checkpoint is 409."""
    return report_service.pause(db, trial_id=trial_id, body=body, caller=caller)
