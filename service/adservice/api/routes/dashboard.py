"""Reads only the dashboard needs: incremental chart columns, learning curves and artifact
names per page."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query, Response

from adclient.schemas import StudyCurves, TrialColumns
from adservice import views
from adservice.api.deps import MAX_ID, ReaderDep, SessionDep, StudyId, listed_numbers
from adservice.api.responses import model_response

router = APIRouter(prefix="/api/v1/dashboard", tags=["dashboard"])


@router.get("/studies/{study_id}/series", response_model=TrialColumns)
def changed_series(
    study_id: StudyId,
    session: SessionDep,
    _: ReaderDep,
    after: Annotated[int, Query(ge=0, le=MAX_ID)] = 0,
    numbers: Annotated[str, Query(max_length=20_000)] = "",
    limit: Annotated[int, Query(ge=1, le=views.SERIES_PAGE)] = views.SERIES_PAGE,
) -> Response:
    """Like ``/studies/{id}/series`` but only trials numbered ``after`` or more, plus the
    trial numbers listed in ``numbers`` (those the page last saw queued or running)."""
    columns = views.trial_columns(
        session,
        study_id=study_id,
        after=after,
        numbers=listed_numbers(numbers, "numbers"),
        limit=limit,
    )
    return model_response(columns)


@router.get("/studies/{study_id}/curves")
def curves(
    study_id: StudyId,
    session: SessionDep,
    _: ReaderDep,
    limit: Annotated[int, Query(ge=1, le=views.CURVES_PAGE)] = 200,
) -> StudyCurves:
    """The reported learning curves of the study's latest ``limit`` trials that reported
    (``more``: earlier ones did too), for the chart of a study's curves."""
    return views.study_curves(session, study_id=study_id, limit=limit)


@router.get("/studies/{study_id}/artifacts")
def artifact_names(
    study_id: StudyId,
    session: SessionDep,
    _: ReaderDep,
    trial_ids: Annotated[str, Query(max_length=20_000)] = "",
) -> dict[int, list[str]]:
    """Artifact names of each listed trial of the study (one request for a table page)."""
    return views.artifact_names(
        session, study_id=study_id, trial_ids=listed_numbers(trial_ids, "trial_ids")
    )
