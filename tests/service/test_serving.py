"""How long a study has waited for a worker (``StudyServing.idle_seconds``) counts from
its latest change: a tell changes a trial, not the study's row."""

from __future__ import annotations

from collections.abc import Callable
from datetime import timedelta

from adclient.schemas import StudyCreate, TellRequest
from adservice.db import Database
from adservice.models import StudyRow, utcnow
from adservice.principals import OPEN_ADMIN
from adservice.repository import studies as study_repo
from adservice.repository import tell as tell_repo
from adservice.repository import trials as trial_repo
from adservice.serving import study_serving


def test_a_study_told_just_now_has_not_waited(new_database_url: Callable[[], str]) -> None:
    """The study's row last changed an hour ago (its one trial's lease); the trial was
    told just now: the study has waited seconds, not an hour, and is not flagged."""
    db = Database(new_database_url())
    try:
        body = StudyCreate.model_validate(
            {
                "name": "idle",
                "space": {"type": "box", "params": [{"name": "x", "low": 0, "high": 1}]},
                "proposer": {"name": "random"},
                "task": {"name": "noop", "external": True},
                "max_trials": 10,
            }
        )
        with db.write() as session:
            study_id = study_repo.create_study(
                session, body=body, representation=None, owner=OPEN_ADMIN
            ).id
            (trial,) = trial_repo.insert_trials(
                session,
                study_id=study_id,
                first_number=trial_repo.reserve_numbers(session, study_id=study_id, count=1),
                vectors=[[0.5]],
                params=[{"x": 0.5}],
                infos=[{}],
                worker_id="w0",
            )
        with db.write() as session:
            request = TellRequest(value=1.0, worker_id="w0")
            tell_repo.tell_trial(session, trial_id=trial.id, body=request, caller=OPEN_ADMIN)
            session.get_one(StudyRow, study_id).updated_at = utcnow() - timedelta(hours=1)
        with db.read() as session:
            serving = study_serving(
                session, study_id=study_id, unserved_seconds=600, server_url="http://x"
            )
    finally:
        db.dispose()
    assert serving is not None and serving.idle_seconds is not None
    assert serving.idle_seconds < 600 and not serving.unserved
