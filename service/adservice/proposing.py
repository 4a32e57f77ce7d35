"""From a study to new trials: snapshot the history, propose off the database, insert.

The proposal itself runs without any database lock held (a qEI fit takes a fraction of
a second); the per-study lock keeps concurrent asks of one study in line so each sees
the trials the previous one created as pending.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from adclient.design import DesignSpace, Representation
from adclient.schemas import BoxSpace, Job, ProposerConfig, StudyCreate, TaskConfig
from adservice import repository
from adservice.convert import study_schema
from adservice.db import Database
from adservice.errors import ConflictError, InvalidError
from adservice.locks import StudyLocks
from adservice.models import StudyRow, TrialRow
from adservice.proposers import ProposalRequest, available, get_proposer
from adservice.proposers.base import empty_history


def parse_space(study: StudyRow) -> BoxSpace | DesignSpace:
    if study.space.get("type") == "design":
        return DesignSpace.model_validate(study.space)
    return BoxSpace.model_validate(study.space)


def search_bounds(study: StudyRow) -> np.ndarray:
    if study.representation is not None:
        return np.asarray(study.representation["bounds"], dtype=np.float64)
    params = study.space["params"]
    return np.array([[p["low"] for p in params], [p["high"] for p in params]], dtype=np.float64)


def trial_params(study: StudyRow, vector: np.ndarray) -> dict[str, Any]:
    """What a person reads: box params by name, or the decoded design."""
    if study.representation is None:
        return {p["name"]: float(x) for p, x in zip(study.space["params"], vector, strict=True)}
    from adclient.decode import decode, design_params

    space = DesignSpace.model_validate(study.space)
    representation = Representation.model_validate(study.representation)
    return design_params(decode(space, representation, vector.tolist()))


def create_study(db: Database, *, body: StudyCreate) -> StudyRow:
    if body.proposer.name not in available():
        raise InvalidError(
            f"proposer.name: unknown proposer {body.proposer.name!r}; "
            f"choose one of {', '.join(available())}"
        )
    representation = None
    if isinstance(body.space, DesignSpace):
        from adservice.representation import build_representation

        representation = build_representation(body.space).model_dump(mode="json")
    with db.write() as session:
        return repository.create_study(session, body=body, representation=representation)


def propose_trials(
    db: Database,
    locks: StudyLocks,
    *,
    study_id: int,
    count: int,
    worker_id: str | None = None,
    lease_seconds: float = 60.0,
) -> list[TrialRow]:
    with locks.hold(db, study_id):
        with db.read() as session:
            study = repository.get_study(session, study_id=study_id)
            repository.check_room(study, count=count)
            config = ProposerConfig.model_validate(study.proposer)
            proposer = get_proposer(config.name)
            bounds = search_bounds(study)
            dim = bounds.shape[1]
            history = (
                repository.study_history(session, study_id=study_id, dim=dim)
                if proposer.needs_history
                else None
            )
        sign = 1.0 if study.direction == "maximize" else -1.0
        empty = empty_history(dim)
        request = ProposalRequest(
            bounds=bounds,
            count=count,
            seed=config.seed,
            n_issued=study.n_trials,
            X=history.X if history else empty,
            y=sign * history.y if history else np.zeros(0),
            failed=history.failed if history else empty,
            pending=history.pending if history else empty,
            n_initial=config.n_initial,
            noisy=config.noisy if config.noisy is not None else study.task is not None,
            options=config.options,
        )
        proposal = proposer.propose(request)
        candidates = np.clip(proposal.candidates, bounds[0], bounds[1])
        params = [trial_params(study, vector) for vector in candidates]
        with db.write() as session:
            return repository.insert_trials(
                session,
                study_id=study_id,
                vectors=candidates.tolist(),
                params=params,
                infos=proposal.info,
                worker_id=worker_id,
                lease_seconds=lease_seconds,
            )


def lease_job(
    db: Database, locks: StudyLocks, *, worker_id: str, lease_seconds: float
) -> Job | None:
    """A queued trial if there is one, else a freshly proposed one from a managed study
    with room; None when there is no work."""
    with db.write() as session:
        trial = repository.lease_queued_trial(
            session, worker_id=worker_id, lease_seconds=lease_seconds
        )
    if trial is None:
        with db.read() as session:
            candidates = repository.studies_wanting_trials(session)
        for study_id in candidates:
            try:
                (trial,) = propose_trials(
                    db,
                    locks,
                    study_id=study_id,
                    count=1,
                    worker_id=worker_id,
                    lease_seconds=lease_seconds,
                )
            except ConflictError:
                continue  # filled or stopped meanwhile: try the next study
            break
    if trial is None:
        return None
    with db.read() as session:
        study = repository.get_study(session, study_id=trial.study_id)
    assert study.task is not None and trial.lease_expires_at is not None
    schema = study_schema(study, {})
    return Job(
        trial_id=trial.id,
        study_id=trial.study_id,
        number=trial.number,
        attempt=trial.attempts,
        vector=trial.vector,
        params=trial.params,
        task=TaskConfig.model_validate(study.task),
        space=schema.space,
        representation=(
            Representation.model_validate(study.representation) if study.representation else None
        ),
        lease_expires_at=trial.lease_expires_at,
    )
