"""Intermediate reports: store a running trial's report, ask the study's pruner."""

from __future__ import annotations

from adclient.pruning import PrunerConfig, ReportRequest, ReportResponse
from adservice import repository_reports
from adservice.db import Database
from adservice.principals import Principal
from adservice.pruners import PruneRequest, should_stop


def report(
    db: Database, *, trial_id: int, body: ReportRequest, caller: Principal
) -> ReportResponse:
    """Record ``(step, value)`` and answer whether the study's pruner would stop the
    trial there. One write transaction: the report and the curves the decision reads are
    the same snapshot, so concurrent reports of one study are decided in some order."""
    with db.write() as session:
        recorded = repository_reports.record_report(
            session, trial_id=trial_id, body=body, caller=caller
        )
        pruner = PrunerConfig.model_validate(recorded.study.pruner or {})
        if pruner.name == "none":
            return ReportResponse(should_stop=False)
        maximize = recorded.study.direction == "maximize"
        others = repository_reports.study_curves(
            session, study_id=recorded.study.id, maximize=maximize, excluding=trial_id
        )
    sign = 1.0 if maximize else -1.0
    request = PruneRequest(
        step=body.step,
        value=sign * body.value,
        previous_steps=recorded.previous_steps,
        best=sign * recorded.best,
        others=others,
    )
    return ReportResponse(should_stop=should_stop(pruner, request))
