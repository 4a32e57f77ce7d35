"""Whether the workers seen lately serve a running managed study (issue 39): the one
rule behind ``adclient status``, ``submit --wait`` and the dashboard's warning, so all
three say the same. A worker serves a study when the tasks and learners it named at
its latest lease (None: any) hold the study's task and its learner."""

from __future__ import annotations

from datetime import timedelta

from sqlalchemy.orm import Session

from adclient.schemas import StudyServing
from adservice.convert import WORKER_RECENT_SECONDS
from adservice.models import WorkerRow, utcnow
from adservice.repository import leases as lease_repo
from adservice.repository import studies as study_repo

RECENT_SECONDS = WORKER_RECENT_SECONDS
"""A worker seen this recently is serving (and not ``gone`` in the workers list)."""


def serves(worker: WorkerRow, *, task: str, learner: str) -> bool:
    return (worker.tasks is None or task in worker.tasks) and (
        worker.learners is None or learner in worker.learners
    )


def study_serving(
    session: Session, *, study_id: int, unserved_seconds: float, server_url: str
) -> StudyServing | None:
    """For a running managed study: how many recently seen workers serve its task and
    learner, or, when none does, what to start (an ``adworker`` for ``server_url``);
    None for a study no worker runs."""
    now = utcnow()
    study = study_repo.get_study(session, study_id=study_id)
    if study.task is None or study.state != "running":
        return None
    task, learner = str(study.task["name"]), str(study.task.get("learner", "fast"))
    external = bool(study.task.get("external", False))
    recent = lease_repo.list_workers(session, seen_since=now - timedelta(seconds=RECENT_SECONDS))
    count = sum(serves(worker, task=task, learner=learner) for worker in recent)
    running = study_repo.state_counts(session, study_ids=[study_id])[study_id].get("running", 0)
    idle = None
    if not running:  # the study's row changes at asks, leases, a new best; a trial at a tell
        told = study_repo.last_finished_at(session, study_id=study_id)
        changed = max(study.updated_at, told) if told is not None else study.updated_at
        idle = max(0.0, (now - changed).total_seconds())
    named = f"task {task!r} with learner {learner!r}"
    if count:
        text = f"{count} serving {named}, seen in the last {RECENT_SECONDS:g} s"
    else:
        others = f" ({len(recent)} other workers serve other tasks or learners)" if recent else ""
        how = (
            f"adworker --server {server_url} --function MODULE:FUNCTION --task {task}"
            if external
            else f"adworker --server {server_url} (with the task's and learner's plugins "
            "importable)"
        )
        text = (
            f"none serving {named} seen in the last {RECENT_SECONDS:g} s{others}: "
            f"the study waits for one; start {how}, and see `adclient workers`"
        )
    return StudyServing(
        task=task,
        learner=learner,
        external=external,
        recent_seconds=RECENT_SECONDS,
        serving=count,
        others=len(recent) - count,
        idle_seconds=idle,
        unserved=count == 0 and idle is not None and idle >= unserved_seconds,
        text=text,
    )
