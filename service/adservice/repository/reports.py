"""Repository of intermediate reports: record a trial's report, read curves.

Same conventions as every module of :mod:`adservice.repository` (an open session,
keyword-only arguments, domain errors, rows out). Nothing here is on the ask/tell hot path.
"""

from __future__ import annotations

import math
from collections import defaultdict
from dataclasses import dataclass

import numpy as np
import sqlalchemy as sa
from sqlalchemy.orm import Session

from adclient.pruning import ReportRequest
from adclient.schemas import TrialState
from adservice.errors import ConflictError, ForbiddenError
from adservice.models import StudyRow, TrialReportRow, TrialRow, utcnow
from adservice.principals import Principal, Role
from adservice.pruners.base import Curve
from adservice.repository.leases import check_lease_token, held_trial
from adservice.repository.studies import check_manager, get_study
from adservice.repository.trials import get_trial

FINISHED = (TrialState.complete, TrialState.failed, TrialState.pruned)


@dataclass(frozen=True)
class Recorded:
    """A stored report with what a pruner needs to decide on it."""

    study: StudyRow
    trial: TrialRow
    previous_steps: np.ndarray
    best: float
    """The trial's best value so far, this report included (as stored, not oriented)."""


def _check_reporter(
    session: Session, *, trial: TrialRow, worker_id: str | None, caller: Principal
) -> None:
    """Who may report: the lease holder (its token, with auth on) naming its worker_id;
    for a trial no worker holds, the study's owner (or an admin)."""
    if worker_id is not None:
        check_lease_token(trial, caller)
        return
    if caller.role == Role.worker:
        raise ForbiddenError("a worker token reports only on trials it holds: give worker_id")
    if trial.worker_id is not None and not caller.is_admin:
        raise ForbiddenError(
            f"trial {trial.id} is leased by worker {trial.worker_id!r}: only the token that "
            "leased it, naming its worker_id, or an admin may report on it"
        )
    check_manager(get_study(session, study_id=trial.study_id), caller)


def record_report(
    session: Session, *, trial_id: int, body: ReportRequest, caller: Principal
) -> Recorded:
    """Store ``(step, value)`` for a running trial. An identical repeat changes nothing;
    another value at a stored step replaces it (a retried attempt trains again). 403 for
    a caller that may not report, 409 once the trial is finished or the lease is lost."""
    trial = get_trial(session, trial_id=trial_id, for_update=True)
    _check_reporter(session, trial=trial, worker_id=body.worker_id, caller=caller)
    if trial.state in FINISHED:
        raise ConflictError(f"trial {trial_id} is already {trial.state}: it takes no reports")
    if body.worker_id is not None:
        held_trial(session, trial_id=trial_id, worker_id=body.worker_id, caller=caller)
    elif trial.state != TrialState.running:
        raise ConflictError(f"trial {trial_id} is {trial.state}: it takes reports while it runs")
    stored = session.get(TrialReportRow, (trial_id, body.step))
    if stored is None:
        session.add(
            TrialReportRow(
                trial_id=trial_id,
                step=body.step,
                study_id=trial.study_id,
                value=body.value,
                created_at=utcnow(),
            )
        )
    elif not math.isclose(stored.value, body.value, rel_tol=1e-12, abs_tol=0.0):
        stored.value = body.value
        stored.created_at = utcnow()
    session.flush()
    earlier = session.execute(
        sa.select(TrialReportRow.step, TrialReportRow.value).where(
            TrialReportRow.trial_id == trial_id
        )
    ).all()
    study = get_study(session, study_id=trial.study_id)
    maximize = study.direction == "maximize"
    # Up to this step: a retried attempt's later steps are stale until it reaches them.
    values = [value for step, value in earlier if step <= body.step]
    return Recorded(
        study=study,
        trial=trial,
        previous_steps=np.asarray([s for s, _ in earlier if s < body.step], dtype=np.int64),
        best=max(values) if maximize else min(values),
    )


def curves_by_trial(session: Session, *, study_id: int, maximize: bool) -> dict[int, Curve]:
    """Every trial's reported curve in a study by trial id (values oriented: larger is
    better), with its state; one indexed query."""
    report = TrialReportRow
    rows = session.execute(
        sa.select(report.trial_id, TrialRow.state, report.step, report.value)
        .join(TrialRow, TrialRow.id == TrialReportRow.trial_id)
        .where(TrialReportRow.study_id == study_id)
        .order_by(TrialReportRow.trial_id, TrialReportRow.step)
    ).all()
    sign = 1.0 if maximize else -1.0
    grouped: dict[int, tuple[str, list[int], list[float]]] = defaultdict(lambda: ("", [], []))
    for trial_id, state, step, value in rows:
        _, steps, values = grouped[trial_id]
        steps.append(step)
        values.append(sign * value)
        grouped[trial_id] = (state, steps, values)
    return {
        trial_id: Curve(
            state=state,
            steps=np.asarray(steps, dtype=np.int64),
            values=np.asarray(values, dtype=np.float64),
        )
        for trial_id, (state, steps, values) in grouped.items()
    }


def trial_reports(session: Session, *, trial_id: int) -> list[TrialReportRow]:
    """A trial's reported curve in order of step (404 for an unknown trial)."""
    get_trial(session, trial_id=trial_id)
    return list(
        session.scalars(
            sa.select(TrialReportRow)
            .where(TrialReportRow.trial_id == trial_id)
            .order_by(TrialReportRow.step)
        )
    )
