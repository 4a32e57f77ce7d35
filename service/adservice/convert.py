"""ORM rows to API schemas: the only way rows leave the service layer."""

from __future__ import annotations

import functools
import json
from datetime import datetime, timedelta
from typing import Any

from adclient.design import DesignSpace
from adclient.objectives import stored_outcomes
from adclient.schemas import ArtifactInfo, Space, Study, Trial, WorkerInfo
from adservice.models import ArtifactRow, StudyRow, TrialRow, WorkerRow, utcnow


def study_schema(row: StudyRow, counts: dict[str, int]) -> Study:
    """``counts``: the study's trials by state (``studies.state_counts``)."""
    outcomes = stored_outcomes(row.outcomes, direction=row.direction)
    objectives = None
    if outcomes.metrics is not None:
        objectives = [
            {"metric": metric, "direction": direction}
            for metric, direction in zip(outcomes.metrics, outcomes.directions, strict=True)
        ]
    study = Study.model_validate(
        {
            "id": row.id,
            "name": row.name,
            "direction": row.direction,
            "directions": outcomes.directions,
            "objective_names": outcomes.names,
            "objectives": objectives,
            "constraints": outcomes.constraints,
            "reference_point": outcomes.reference_point,
            "state": row.state,
            "managed": row.task is not None,
            "space": row.space,
            "proposer": row.proposer,
            "pruner": row.pruner,
            "task": row.task,
            "max_trials": row.max_trials,
            "max_attempts": row.max_attempts,
            "n_trials": row.n_trials,
            "n_queued": counts.get("queued", 0),
            "n_running": counts.get("running", 0),
            "n_complete": counts.get("complete", 0),
            "n_failed": counts.get("failed", 0),
            "n_pruned": counts.get("pruned", 0),
            "n_paused": counts.get("paused", 0),
            "best_value": row.best_value,
            "best_trial_id": row.best_trial_id,
            "metadata": row.metadata_,
            "user_attrs": row.user_attrs,
            "created_by": row.created_by,
            "created_at": row.created_at,
            "updated_at": row.updated_at,
            "proposal_error": row.proposal_error,
            "proposal_failures": row.proposal_failures or 0,
            "proposal_retry_at": row.proposal_retry_at,
            "proposal_fallbacks": row.proposal_fallbacks or 0,
            "proposal_fallback_reason": row.proposal_fallback_reason,
            "fixed": searches_nothing(row),
        }
    )
    study.searched_params = searched_keys(study.space, row.space)
    return study


def searched_keys(space: Space, stored: dict[str, Any]) -> list[str]:
    """The params keys a study searches (``Study.searched_params``); a design space's
    (``stored`` as JSON) worked out once per space, not at every read of the study."""
    if isinstance(space, DesignSpace):
        return list(_design_searched(json.dumps(stored, sort_keys=True)))
    return [param.name for param in space.params]


def design_searched(stored: dict[str, Any]) -> tuple[str, ...]:
    """The params keys a design space (as stored) searches, as ``searched_keys`` gives
    them; empty for a space of another type."""
    if stored.get("type") != "design":
        return ()
    return _design_searched(json.dumps(stored, sort_keys=True))


@functools.lru_cache(maxsize=256)
def _design_searched(space: str) -> tuple[str, ...]:
    from adclient.decode import searched_params

    return tuple(sorted(searched_params(DesignSpace.model_validate_json(space))))


def searches_nothing(row: StudyRow) -> bool:
    """Whether a study's space is one design, from what is stored (no space parsed): a
    design space whose search box has no coordinate, or a template without params."""
    if row.representation is not None:
        return not row.representation["bounds"][0]
    return row.space.get("type") == "template" and not row.space.get("params")


def trial_schema(row: TrialRow) -> Trial:
    return Trial.model_validate(row, from_attributes=True)


def artifact_schema(row: ArtifactRow) -> ArtifactInfo:
    return ArtifactInfo.model_validate(row, from_attributes=True)


WORKER_RECENT_SECONDS = 90.0
"""A worker heard from this recently is there (serving, idle or working): an idle
adworker asks for work at least every 30 s, a working one heartbeats at least every 20 s.
Past it the worker is ``gone``: a stopped adworker says nothing as it exits."""


def worker_schema(row: WorkerRow, *, now: datetime | None = None) -> WorkerInfo:
    info = WorkerInfo.model_validate(row, from_attributes=True)
    if (now or utcnow()) - row.last_seen_at > timedelta(seconds=WORKER_RECENT_SECONDS):
        info.state = "gone"
    else:
        info.state = "idle" if row.current_trial_id is None else "working"
    return info
