"""What a job's controller starts from, downloaded into its job folder before the
runner reads it: a promoted trial's own checkpoint (``job.resume``), another design's
(``job.transfer``, ``task.transfer: nearest``), or the study's shared controller
(``job.shared``).

A refused token (``Unauthorized``, ``Forbidden``) is raised as it comes: the job fails
with it, and the worker stops if the server refuses that tell too.
"""

from __future__ import annotations

import logging
from pathlib import Path

from adclient.client import Client
from adclient.errors import ApiError, Forbidden, NotFound, Unauthorized
from adclient.schemas import Job
from adworker.runner import SHARED_FILE, TRANSFER_FILE, Cancelled

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
        data = _of_own_study(client, job, source, job.transfer.artifact, "training from scratch")
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
    if data is None:
        return
    jobdir.mkdir(parents=True, exist_ok=True)
    (jobdir / TRANSFER_FILE).write_bytes(data)
    log.info(
        "trial %s: starting from trial %s's controller (spec distance %.3f)",
        job.trial_id,
        source,
        job.transfer.distance,
    )


def fetch_shared(client: Client, job: Job, jobdir: Path) -> None:
    """The shared controller's version ``job.shared`` names, into the job folder
    (``SHARED_FILE``). One of another study, or whose file is not there, is skipped with
    the reason logged: the design then starts from the study's initial weights (and its
    update replaces that version). A download that fails otherwise leaves the job
    (``Cancelled``: its lease is given back or expires, and it is done again), since a
    design trained from the initial weights in its place would replace everything the
    study learned."""
    assert job.shared is not None
    initial = "starting from the study's initial weights"
    try:
        data = _of_own_study(client, job, job.shared.trial_id, job.shared.artifact, initial)
    except (Unauthorized, Forbidden):
        raise
    except NotFound as exc:
        log.warning(
            "trial %s: shared controller version %d is not there (%s): %s",
            job.trial_id,
            job.shared.version,
            exc,
            initial,
        )
        return
    except ApiError as exc:
        # Trained from the initial weights, its update would replace the study's version.
        version = job.shared.version
        raise Cancelled(f"shared controller version {version} not downloaded: {exc}") from exc
    if data is None:
        return
    jobdir.mkdir(parents=True, exist_ok=True)
    (jobdir / SHARED_FILE).write_bytes(data)
    log.info(
        "trial %s: starting from shared controller version %d", job.trial_id, job.shared.version
    )


def _of_own_study(
    client: Client, job: Job, trial_id: int, artifact: str, otherwise: str
) -> bytes | None:
    """``trial_id``'s ``artifact``, or None (logged, saying ``otherwise``) when that
    trial is of another study than ``job``'s: a controller starts only from its own
    study's designs."""
    study_id = client.get_trial(trial_id).study_id
    if study_id != job.study_id:
        log.warning(
            "trial %s: the controller of trial %s is of study %s, not %s: %s",
            job.trial_id,
            trial_id,
            study_id,
            job.study_id,
            otherwise,
        )
        return None
    return client.get_artifact(trial_id, artifact)
