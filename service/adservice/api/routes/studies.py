"""Studies: create, list, read, ask, stop, delete, user attributes, and the views the
dashboard draws from."""

from __future__ import annotations

import re
from typing import Annotated

from fastapi import APIRouter, Query, Request, Response
from pydantic import AfterValidator

from adclient.schemas import (
    MAX_TRIAL_PAGE,
    MAX_WORKER_PAGE,
    AskRequest,
    AskResponse,
    Study,
    StudyCreate,
    StudyServing,
    StudySpread,
    StudyUpdate,
    Trial,
    TrialColumns,
    TrialState,
    WorkerInfo,
)
from adservice import serving, views
from adservice.api.bodies import read_body
from adservice.api.deps import (
    MAX_ID,
    ArtifactStoreDep,
    DatabaseDep,
    PageOffset,
    ProposingDep,
    ReaderDep,
    SessionDep,
    SettingsDep,
    StudyId,
    UserDep,
    WorkerLimit,
    listed_numbers,
)
from adservice.api.responses import model_response
from adservice.convert import study_schema, trial_schema, worker_schema
from adservice.repository import edits as edit_repo
from adservice.repository import leases as lease_repo
from adservice.repository import studies as study_repo
from adservice.repository import trials as trial_repo
from adservice.services import studies as study_service
from adservice.services import trials as trial_service

router = APIRouter(prefix="/api/v1/studies", tags=["studies"])

TRIAL_ORDER = re.compile(
    r"(number|value|state|created_at|finished_at|worker_id|attempts|duration"
    r"|param:[A-Za-z0-9][A-Za-z0-9_.\-]{0,127})"
)


def _trial_order(value: str) -> str:
    if not TRIAL_ORDER.fullmatch(value):
        raise ValueError(
            "expected number, value, state, created_at, finished_at, worker_id, attempts, "
            "duration, or param:NAME with a param's name"
        )
    return value


TrialOrder = Annotated[
    str,
    Query(description="a column, `duration` (finish minus start), or `param:NAME`"),
    AfterValidator(_trial_order),
]


@router.post("", status_code=201, include_in_schema=False)
async def create_study_served(request: Request, proposing: ProposingDep, caller: UserDep) -> Study:
    """``create_study``, its body read off the event loop (``adservice.api.bodies``)."""
    body = await read_body(request, StudyCreate)
    row = await study_service.create_study(
        proposing.db,
        proposing.expansions,
        request.app.state.creations,
        body=body,
        owner=caller,
        budget=proposing.runner.budget,
        disconnected=request.is_disconnected,
    )
    return study_schema(row, {})


@router.post("", status_code=201)
async def create_study(body: StudyCreate, caller: UserDep) -> Study:
    # The operation as documented; create_study_served, registered before it, serves
    # every request (its body read off the event loop).
    raise AssertionError("served by create_study_served")


@router.get("")
def list_studies(session: SessionDep, _: ReaderDep) -> list[Study]:
    rows = study_repo.list_studies(session)
    counts = study_repo.state_counts(session, study_ids=[row.id for row in rows])
    return [study_schema(row, counts[row.id]) for row in rows]


@router.get("/{study_id}")
def get_study(study_id: StudyId, session: SessionDep, _: ReaderDep) -> Study:
    row = study_repo.get_study(session, study_id=study_id)
    counts = study_repo.state_counts(session, study_ids=[study_id])
    return study_schema(row, counts[study_id])


@router.post("/{study_id}/ask", response_model=AskResponse)
async def ask(
    study_id: StudyId,
    body: AskRequest,
    proposing: ProposingDep,
    caller: UserDep,
) -> Response:
    asked = await trial_service.ask_trials(
        proposing, study_id=study_id, count=body.count, caller=caller
    )
    return model_response(AskResponse(trials=asked))


@router.post("/{study_id}/stop")
def stop_study(study_id: StudyId, db: DatabaseDep, caller: UserDep) -> Study:
    with db.write() as session:
        row = study_repo.stop_study(session, study_id=study_id, caller=caller)
        counts = study_repo.state_counts(session, study_ids=[study_id])
    return study_schema(row, counts[study_id])


@router.delete("/{study_id}", status_code=204, response_class=Response)
def delete_study(
    study_id: StudyId,
    db: DatabaseDep,
    store: ArtifactStoreDep,
    caller: UserDep,
    force: Annotated[
        bool, Query(description="also while workers hold leases on its trials (cancelled)")
    ] = False,
) -> Response:
    """Delete the study with its trials, reports and artifacts (its owner or an admin);
    409 while workers hold leases on its trials, unless ``force``."""
    study_service.delete_study(db, store, study_id=study_id, caller=caller, force=force)
    return Response(status_code=204)


@router.patch("/{study_id}")
def update_study(study_id: StudyId, body: StudyUpdate, db: DatabaseDep, caller: UserDep) -> Study:
    """Set user attributes (a null value deletes its key); its owner or an admin."""
    with db.write() as session:
        row = edit_repo.set_study_user_attrs(
            session, study_id=study_id, changes=body.user_attrs, caller=caller
        )
        counts = study_repo.state_counts(session, study_ids=[study_id])
    return study_schema(row, counts[study_id])


@router.get("/{study_id}/trials")
def list_trials(
    study_id: StudyId,
    session: SessionDep,
    response: Response,
    _: ReaderDep,
    state: TrialState | None = None,
    offset: Annotated[int, Query(ge=0, le=MAX_ID)] = 0,
    limit: Annotated[int, Query(ge=1, le=MAX_TRIAL_PAGE)] = MAX_TRIAL_PAGE,
    after: Annotated[
        int, Query(ge=0, le=MAX_ID, description="only trials numbered `after` or more")
    ] = 0,
    order_by: TrialOrder = "number",
    desc: bool = False,
    numbers: Annotated[
        str,
        Query(
            max_length=20_000,
            description="only the trials of these numbers (comma-separated, at most 1000):"
            " the dashboard's filters by param and score range",
        ),
    ] = "",
) -> list[Trial]:
    """Trials, optionally filtered, one page at a time (a bounded page keeps one request
    cheap); the total that match is in ``X-Total-Count``. Page with ``offset``, or in
    order of number with ``after`` (the last number seen plus one), which skips no trial
    when others change state between pages."""
    rows, total = trial_repo.list_trials(
        session,
        study_id=study_id,
        state=state,
        numbers=listed_numbers(numbers, "numbers") if numbers else None,
        after=after,
        offset=offset,
        limit=limit,
        order_by=order_by,
        descending=desc,
    )
    response.headers["X-Total-Count"] = str(total)
    return [trial_schema(row) for row in rows]


@router.get("/{study_id}/best")
def best_trial(study_id: StudyId, session: SessionDep, _: ReaderDep) -> Trial:
    """The best complete (and feasible) trial of a study of one objective; a study of
    several has its best trials at ``/pareto`` (409 here)."""
    return trial_schema(trial_repo.best_trial(session, study_id=study_id))


@router.get("/{study_id}/pareto")
def pareto_trials(study_id: StudyId, session: SessionDep, _: ReaderDep) -> list[Trial]:
    """The complete, feasible trials that no other one dominates (Optuna's
    ``best_trials``), by number; for one objective, those with the best value."""
    return [trial_schema(row) for row in trial_repo.pareto_trials(session, study_id=study_id)]


@router.get("/{study_id}/spread")
def value_spread(study_id: StudyId, session: SessionDep, _: ReaderDep) -> StudySpread:
    """Each objective's n, mean, standard deviation, min, median and max over the
    study's complete trials: for a study of one design (``fixed``), its repeats."""
    return views.value_spread(session, study_id=study_id)


@router.get("/{study_id}/workers")
def study_workers(
    study_id: StudyId,
    session: SessionDep,
    _: ReaderDep,
    offset: PageOffset = 0,
    limit: WorkerLimit = MAX_WORKER_PAGE,
) -> list[WorkerInfo]:
    rows = lease_repo.list_workers(session, study_id=study_id, offset=offset, limit=limit)
    return [worker_schema(row) for row in rows]


@router.get("/{study_id}/serving")
def study_serving(
    study_id: StudyId,
    request: Request,
    session: SessionDep,
    settings: SettingsDep,
    _: ReaderDep,
) -> StudyServing | None:
    """Whether the workers seen in the last 90 s serve a running managed study's task
    and learner, and what to start when none does; null for a study no worker runs."""
    return serving.study_serving(
        session,
        study_id=study_id,
        unserved_seconds=settings.unserved_seconds,
        server_url=settings.public_url or str(request.base_url).rstrip("/"),
    )


@router.get("/{study_id}/series", response_model=TrialColumns)
def study_series(
    study_id: StudyId,
    session: SessionDep,
    _: ReaderDep,
    after: Annotated[
        int, Query(ge=0, le=MAX_ID, description="only trials numbered `after` or more")
    ] = 0,
    limit: Annotated[int, Query(ge=1, le=views.SERIES_PAGE)] = views.SERIES_PAGE,
) -> Response:
    """The trials as columns (number, state, value, params; values and feasible for a
    study of several objectives or with constraints), a page at a time: a page
    ends after ``limit`` trials or about 250,000 param values, and ``next`` is where the
    following one starts."""
    return model_response(views.trial_columns(session, study_id=study_id, after=after, limit=limit))
