"""Read-side queries the dashboard needs beyond the plain API: the trials that changed
since a page last looked, and which artifacts a page of trials has.

A complete or failed trial never changes again, so a page that holds a study's trials
only needs the new ones and those it last saw queued or running.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from typing import Any

import sqlalchemy as sa
from sqlalchemy.orm import Session

from adservice import repository
from adservice.models import ArtifactRow, TrialRow

_PARAMS_TEXT = sa.type_coerce(TrialRow.params, sa.Text)
"""The params column as the driver returns it: JSON text on SQLite, which ``json.loads``
reads several times faster than the ORM's JSON type does row by row; PostgreSQL's
driver hands back parsed objects already."""


def _columns(rows: Sequence[Any]) -> dict[str, Any]:
    """Trials as parallel columns, as ``repository.trial_columns`` gives them; params of
    numbers only (what can be plotted)."""
    params = [json.loads(row[3]) if isinstance(row[3], str | bytes) else row[3] for row in rows]
    names: dict[str, None] = {}
    for values in params:
        for key, value in values.items():
            if isinstance(value, int | float) and not isinstance(value, bool):
                names.setdefault(key, None)
    return {
        "number": [row[0] for row in rows],
        "state": [row[1] for row in rows],
        "value": [row[2] for row in rows],
        "params": {name: [values.get(name) for values in params] for name in names},
    }


def changed_trial_columns(
    session: Session, *, study_id: int, after: int, numbers: Sequence[int]
) -> dict[str, Any]:
    """Columns of the trials numbered ``after`` or more, plus those numbered in
    ``numbers`` (the ones the caller last saw still open)."""
    repository.get_study(session, study_id=study_id)
    changed = TrialRow.number >= after
    if numbers:
        changed = sa.or_(changed, TrialRow.number.in_(sorted(set(numbers))))
    rows = session.execute(
        sa.select(TrialRow.number, TrialRow.state, TrialRow.value, _PARAMS_TEXT)
        .where(TrialRow.study_id == study_id, changed)
        .order_by(TrialRow.number)
    ).all()
    return _columns(rows)


def artifact_names(
    session: Session, *, study_id: int, trial_ids: Sequence[int]
) -> dict[int, list[str]]:
    """Names of the artifacts of each of ``trial_ids`` that belongs to the study."""
    repository.get_study(session, study_id=study_id)
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
