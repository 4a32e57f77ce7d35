"""Intermediate reports: store a running trial's report, ask the study's pruner; with
ASHA promotion, pause a stopped trial and promote the paused ones that qualify."""

from __future__ import annotations

from adclient.pruning import PauseRequest, PrunerConfig, ReportRequest, ReportResponse
from adclient.schemas import Trial
from adservice.convert import trial_schema
from adservice.db import Database
from adservice.principals import Principal
from adservice.pruners import PruneRequest, should_stop
from adservice.pruners.asha import rungs
from adservice.repository import promotion as promotion_repo
from adservice.repository import reports as report_repo


def report(
    db: Database, *, trial_id: int, body: ReportRequest, caller: Principal
) -> ReportResponse:
    """Record ``(step, value)`` and answer whether the study's pruner would stop the
    trial there (``pause``: by pausing it, for a worker under ASHA with promotion). One
    write transaction: the report and the curves the decision reads are the same
    snapshot, so concurrent reports of one study are decided in some order; a report
    that brings a value to a rung promotes the paused trials that now qualify there."""
    with db.write() as session:
        recorded = report_repo.record_report(session, trial_id=trial_id, body=body, caller=caller)
        pruner = PrunerConfig.model_validate(recorded.study.pruner or {})
        if pruner.name == "none":
            return ReportResponse(should_stop=False)
        maximize = recorded.study.direction == "maximize"
        curves = report_repo.curves_by_trial(session, study_id=recorded.study.id, maximize=maximize)
        sign = 1.0 if maximize else -1.0
        request = PruneRequest(
            step=body.step,
            value=sign * body.value,
            previous_steps=recorded.previous_steps,
            best=sign * recorded.best,
            others=[curve for other, curve in curves.items() if other != trial_id],
        )
        promotion = promotion_repo.asha_promotion(pruner)
        if promotion is not None and any(
            rungs(promotion, above=request.last_step_before, up_to=body.step)
        ):
            promotion_repo.promote(
                session, study_id=recorded.study.id, options=promotion, curves=curves
            )
    stop = should_stop(pruner, request)
    pause = stop and promotion is not None and body.worker_id is not None
    return ReportResponse(should_stop=stop, pause=pause)


def pause(db: Database, *, trial_id: int, body: PauseRequest, caller: Principal) -> Trial:
    """Pause a held trial with its uploaded checkpoint (see
    :func:`adservice.repository.promotion.pause_trial`)."""
    with db.write() as session:
        row = promotion_repo.pause_trial(session, trial_id=trial_id, body=body, caller=caller)
        return trial_schema(row)
