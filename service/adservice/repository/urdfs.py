"""Repository of trials' URDFs (``trial_urdfs``): a template study's trial expanded once,
when its params were fixed, and served by every read; a trial whose params the
template does not expand at keeps why, and is failed with it.

Same conventions as every module of :mod:`adservice.repository`.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from datetime import datetime
from typing import cast

import sqlalchemy as sa
from sqlalchemy.dialects import postgresql, sqlite
from sqlalchemy.orm import Session

from adclient.schemas import Trial, TrialState
from adservice.expansions import Expansion
from adservice.models import StudyRow, TrialRow, TrialURDFRow, UTCDateTime, utcnow
from adservice.repository._shared import FINISH
from adservice.repository.studies import finish_if_done

_urdfs = cast(sa.Table, TrialURDFRow.__table__)
_trials = cast(sa.Table, TrialRow.__table__)
_studies = cast(sa.Table, StudyRow.__table__)


def store_urdfs(session: Session, *, expansions: Mapping[int, Expansion]) -> None:
    """Each trial's expansion by trial id, unless one is stored already (a read of a
    trial stored before URDFs were may store it meanwhile) or the trial is gone."""
    if not expansions:
        return
    insert = postgresql.insert if session.get_bind().dialect.name == "postgresql" else sqlite.insert
    existing = sa.select(
        _trials.c.id,
        sa.bindparam("text", type_=sa.Text),
        sa.bindparam("reason", type_=sa.Text),
        sa.bindparam("now", type_=UTCDateTime),
    ).where(_trials.c.id == sa.bindparam("tid"))
    statement = (
        insert(_urdfs)
        .from_select(["trial_id", "urdf", "error", "created_at"], existing)
        .on_conflict_do_nothing()
    )
    now = utcnow()
    session.execute(
        statement,
        [
            {"tid": trial_id, "text": expansion.urdf, "reason": expansion.error, "now": now}
            for trial_id, expansion in expansions.items()
        ],
    )


def stored_urdfs(session: Session, *, trial_ids: Iterable[int]) -> dict[int, Expansion]:
    """The stored expansions of these trials, by trial id (those with none left out)."""
    rows = session.execute(
        sa.select(_urdfs.c.trial_id, _urdfs.c.urdf, _urdfs.c.error).where(
            _urdfs.c.trial_id.in_(list(trial_ids))
        )
    )
    return {row.trial_id: Expansion(urdf=row.urdf, error=row.error) for row in rows}


def fail_unexpanded(session: Session, *, errors: Mapping[int, str]) -> dict[int, Trial]:
    """Fail the new trials (queued or running) whose params the template does not expand
    at, each with the template's message, as a worker's failed tell would: the proposer
    learns from them, and no worker gets them. Returns the failed trials by id."""
    now = utcnow()
    failed: dict[int, Trial] = {}
    for trial_id, error in errors.items():
        row = FINISH[False, False].row(
            session,
            {
                "tid": trial_id,
                "wid": None,
                "tok": None,
                "state": TrialState.failed.value,
                "value": None,
                "message": f"the template does not expand at the trial's params: {error}",
                "metrics": {},
                "now": now,
            },
        )
        if row is None:  # finished or gone meanwhile
            continue
        failed[trial_id] = Trial.model_validate(row)
    for study_id in sorted({trial.study_id for trial in failed.values()}):
        finish_if_done(session, study_id=study_id)
    return failed


def back_off(
    session: Session, *, study_id: int, failures: int, error: str, retry_at: datetime
) -> None:
    """The study's expansions failed or ran slow ``failures`` times in a row: recorded as
    its proposal failures are (``proposal_error``, ``proposal_failures``), and leases skip
    it until ``retry_at`` (a proposal's reservation clears the record, so the count in a
    row is the caller's)."""
    session.execute(
        sa.update(_studies)
        .where(_studies.c.id == study_id)
        .values(proposal_failures=failures, proposal_error=error, proposal_retry_at=retry_at)
    )
