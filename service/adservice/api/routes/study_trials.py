"""A study's trials handed over by its owner: enqueued for evaluation, or already
evaluated (a warm start). Listing them is the studies router's ``GET``."""

from __future__ import annotations

from fastapi import APIRouter

from adclient.schemas import Trial, TrialAddBody
from adservice.api.deps import ProposingDep, StudyId, UserDep
from adservice.services import trials as trial_service

router = APIRouter(prefix="/api/v1/studies", tags=["studies"])


@router.post(
    "/{study_id}/trials",
    status_code=201,
    responses={409: {"description": "the study is not running or has no room for them"}},
)
async def add_trials(
    study_id: StudyId, body: TrialAddBody, proposing: ProposingDep, caller: UserDep
) -> Trial | list[Trial]:
    """One trial (an object) or several (a list), stored together or not at all: without
    an outcome a trial is queued (the next ask hands it out before proposing; a worker
    leases it for a managed study), with ``value`` or ``state`` it is an evaluation
    already made, which the proposer learns from. Answers the trials in the body's
    shape and order (with ``skip_if_exists``, an existing trial in a new one's place).
    A template study's trials are expanded first: one whose params the template does not
    expand at is a 422 (a failed one keeps why), and a full expansion queue a 503."""
    adds = body if isinstance(body, list) else [body]
    trials = await trial_service.add_trials(proposing, study_id=study_id, adds=adds, caller=caller)
    return trials if isinstance(body, list) else trials[0]
