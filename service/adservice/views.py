"""Read-side queries for charts and the dashboard: trials as columns, a page at a time
and optionally only those that changed since a page last looked, and which artifacts a
page of trials has, the learning curves trials reported, and how the values spread.

A complete or failed trial never changes again, so a page that holds a study's trials
only needs the new ones and those it last saw queued or running.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from typing import Any

import sqlalchemy as sa
from sqlalchemy.orm import Session

from adclient.objectives import stored_outcomes
from adclient.schemas import (
    ObjectiveSpread,
    StudyCurves,
    StudySpread,
    TrialColumns,
    TrialCurve,
    TrialState,
)
from adservice.convert import design_searched, searches_nothing
from adservice.models import ArtifactRow, TrialReportRow, TrialRow
from adservice.repository import studies as study_repo

SERIES_PAGE = 5000
"""The most trials one page of columns holds (also the default)."""
SERIES_CELLS = 250_000
"""The most param values one page holds: a page ends early when its trials carry many
params, so no request costs more than about this many (6,400 trials of 256 params in one
answer took 3 to 5 s of CPU and 32 MB)."""
_CHUNK = 250
"""Trials read per query while a page fills: a page that ends on the cell budget reads
at most this many trials it does not use."""

_PARAMS_TEXT = sa.type_coerce(TrialRow.params, sa.Text)
"""The params column as the driver returns it: JSON text on SQLite, which ``json.loads``
reads several times faster than the ORM's JSON type does row by row; PostgreSQL's
driver hands back parsed objects already."""
_STATES = {state.value: state for state in TrialState}


def trial_columns(
    session: Session,
    *,
    study_id: int,
    after: int = 0,
    numbers: Sequence[int] = (),
    limit: int = SERIES_PAGE,
) -> TrialColumns:
    """Columns of the study's trials numbered ``after`` or more, plus those numbered in
    ``numbers`` (the ones the caller last saw still open), in order of number: at most
    ``limit`` trials and about ``SERIES_CELLS`` param values. ``next`` says where the
    following page starts; the listed ``numbers`` below it are all in this page."""
    study = study_repo.get_study(session, study_id=study_id)
    outcomes = stored_outcomes(study.outcomes, direction=study.direction)
    choices = {
        param["name"]
        for param in study.space.get("params", [])
        if param.get("type") == "categorical"
    }
    # A design study's searched structure and catalogue choices are charted as choices
    # too (text), as its best design lists them.
    chosen = {
        name
        for name in design_searched(study.space)
        if name == "structure" or name.endswith(".choice")
    }
    changed = TrialRow.number >= after
    if numbers:
        changed = sa.or_(changed, TrialRow.number.in_(sorted(set(numbers))))
    # A study's values and feasibility are read only when it has them: a plain study's
    # page costs what it did.
    values_column: Any = TrialRow.values if outcomes.multi else sa.null()
    feasible_column: Any = TrialRow.feasible if outcomes.constraints else sa.null()
    query = (
        sa.select(
            TrialRow.number,
            TrialRow.state,
            TrialRow.value,
            _PARAMS_TEXT,
            values_column,
            feasible_column,
        )
        .where(TrialRow.study_id == study_id, changed)
        .order_by(TrialRow.number)
    )
    rows: list[tuple[int, str, float | None, dict[str, Any], list[float] | None, bool | None]] = []
    cells, last, more = 0, -1, True
    while more and len(rows) < limit and cells < SERIES_CELLS:
        wanted = min(_CHUNK, limit - len(rows))
        chunk = session.execute(query.where(TrialRow.number > last).limit(wanted + 1)).all()
        more = len(chunk) > wanted
        for number, state, value, text, values, feasible in chunk[:wanted]:
            row_params = json.loads(text) if isinstance(text, str | bytes) else text
            rows.append((number, state, value, row_params, values, feasible))
            cells += len(row_params)
            last = number
            if cells >= SERIES_CELLS:
                more = more or number != chunk[-1][0]
                break
    names: dict[str, None] = {}
    for row in rows:
        names.update(dict.fromkeys(row[3]))
    params: dict[str, list[float | str | bool | None]] = {}
    for name in names:
        found = [row[3].get(name) for row in rows]
        # Numbers only (what can be plotted); exact types, as parsed JSON has, leave out bools.
        # A categorical param's choices are plotted too (the dashboard places them on ticks).
        kinds = (float, int, str, bool) if name in choices | chosen else (float, int)
        column = [item if type(item) in kinds else None for item in found]
        if any(item is not None for item in column):
            params[name] = column
    return TrialColumns.model_construct(
        number=[row[0] for row in rows],
        state=[_STATES[row[1]] for row in rows],
        value=[row[2] for row in rows],
        params=params,
        values=[row[4] for row in rows] if outcomes.multi else None,
        feasible=[row[5] for row in rows] if outcomes.constraints else None,
        next=last + 1 if more else None,
    )


def value_spread(session: Session, *, study_id: int) -> StudySpread:
    """Each objective's spread over the study's complete trials (``StudySpread``): for a
    study of one design, its repeats. One query of their values."""
    study = study_repo.get_study(session, study_id=study_id)
    outcomes = stored_outcomes(study.outcomes, direction=study.direction)
    rows = session.execute(
        sa.select(TrialRow.value, TrialRow.values).where(
            TrialRow.study_id == study_id, TrialRow.state == TrialState.complete.value
        )
    ).all()
    columns: list[list[float]] = [[] for _ in outcomes.names]
    for value, values in rows:
        told = values if outcomes.multi else [value]
        for column, item in zip(columns, told or [], strict=False):
            if item is not None:
                column.append(float(item))
    return StudySpread(
        study_id=study_id,
        fixed=searches_nothing(study),
        objectives=[
            ObjectiveSpread.of(name, column)
            for name, column in zip(outcomes.names, columns, strict=True)
        ],
    )


CURVES_PAGE = 500
"""Trials a page of curves holds at most (``limit``)."""


def study_curves(session: Session, *, study_id: int, limit: int) -> StudyCurves:
    """The reported curves of the study's latest ``limit`` trials that reported: two
    indexed queries (which trials, then their points), whatever the study's size."""
    study_repo.get_study(session, study_id=study_id)
    latest = session.execute(
        sa.select(TrialRow.id, TrialRow.number, TrialRow.state)
        .where(
            TrialRow.study_id == study_id,
            sa.exists().where(TrialReportRow.trial_id == TrialRow.id),
        )
        .order_by(TrialRow.number.desc())
        .limit(limit + 1)
    ).all()
    more = len(latest) > limit
    trials = sorted(latest[:limit], key=lambda row: row.number)
    points: dict[int, list[tuple[int, float]]] = {row.id: [] for row in trials}
    if trials:
        for trial_id, step, value in session.execute(
            sa.select(TrialReportRow.trial_id, TrialReportRow.step, TrialReportRow.value)
            .where(TrialReportRow.trial_id.in_(list(points)))
            .order_by(TrialReportRow.trial_id, TrialReportRow.step)
        ):
            points[trial_id].append((step, value))
    return StudyCurves(
        curves=[
            TrialCurve(
                trial_id=row.id,
                number=row.number,
                state=row.state,
                steps=[step for step, _ in points[row.id]],
                values=[value for _, value in points[row.id]],
            )
            for row in trials
        ],
        more=more,
    )


def artifact_names(
    session: Session, *, study_id: int, trial_ids: Sequence[int]
) -> dict[int, list[str]]:
    """Names of the artifacts of each of ``trial_ids`` that belongs to the study."""
    study_repo.get_study(session, study_id=study_id)
    names: dict[int, list[str]] = {trial_id: [] for trial_id in trial_ids}
    if not trial_ids:
        return names
    rows = session.execute(
        sa.select(ArtifactRow.trial_id, ArtifactRow.name)
        .join(TrialRow, TrialRow.id == ArtifactRow.trial_id)
        .where(TrialRow.study_id == study_id, ArtifactRow.trial_id.in_(sorted(set(trial_ids))))
        .order_by(ArtifactRow.trial_id, ArtifactRow.name)
    ).all()
    for trial_id, name in rows:
        names[trial_id].append(name)
    return names
