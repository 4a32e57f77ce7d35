"""What a job's controller starts from, downloaded into its job folder before the
runner reads it: a promoted trial's own checkpoint (``job.resume``), another design's
(``job.transfer``, ``task.transfer: nearest``), or the study's shared controller
(``job.shared``: :func:`adworker.sharing.fetch_shared`).

A refused token (``Unauthorized``, ``Forbidden``) is raised as it comes: the worker
stops on it when it next tells the server anything.
"""

from __future__ import annotations

import logging
from pathlib import Path

from adclient.client import Client
from adclient.errors import ApiError, Forbidden, Unauthorized
from adclient.schemas import Job
from adworker.runner import TRANSFER_FILE, Cancelled
from adworker.sharing import fetch_shared

log = logging.getLogger("adworker")


def fetch_start(client: Client, job: Job, jobdir: Path) -> None:
    """Whatever ``job`` starts from, into ``jobdir`` (nothing for a design from scratch)."""
    if job.resume is not None:
        fetch_checkpoint(client, job, jobdir)
    elif job.transfer is not None:
        fetch_transfer(client, job, jobdir)
    elif job.shared is not None:
        fetch_shared(client, job, jobdir)


def fetch_checkpoint(client: Client, job: Job, jobdir: Path) -> None:
    """A promoted trial's checkpoint into its job folder, where the runner reads it;
    a download that fails leaves the job (its lease expires and it is retried)."""
    assert job.resume is not None
    try:
        data = client.get_artifact(job.trial_id, job.resume.artifact)
    except (Unauthorized, Forbidden):
        raise
    except ApiError as exc:
        raise Cancelled(f"checkpoint {job.resume.artifact!r} not downloaded: {exc}") from exc
    jobdir.mkdir(parents=True, exist_ok=True)
    (jobdir / job.resume.artifact).write_bytes(data)
    log.info("trial %s: resuming from step %d", job.trial_id, job.resume.step)


def fetch_transfer(client: Client, job: Job, jobdir: Path) -> None:
    """The checkpoint a job's controller starts from (``job.transfer``) into its job
    folder. One that is not there, not of this study or not downloaded is skipped
    with the reason logged: the design then trains from scratch."""
    assert job.transfer is not None
    source = job.transfer.trial_id
    try:
        study_id = client.get_trial(source).study_id
        if study_id != job.study_id:
            log.warning(
                "trial %s: transfer source %s is of study %s, not %s: training from scratch",
                job.trial_id,
                source,
                study_id,
                job.study_id,
            )
            return
        data = client.get_artifact(source, job.transfer.artifact)
    except (Unauthorized, Forbidden):
        raise
    except ApiError as exc:
        log.warning(
            "trial %s: checkpoint of trial %s not downloaded (%s): training from scratch",
            job.trial_id,
            source,
            exc,
        )
        return
    jobdir.mkdir(parents=True, exist_ok=True)
    (jobdir / TRANSFER_FILE).write_bytes(data)
    log.info(
        "trial %s: starting from trial %s's controller (spec distance %.3f)",
        job.trial_id,
        source,
        job.transfer.distance,
    )
