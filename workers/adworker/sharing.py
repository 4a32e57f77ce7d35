"""A worker's side of a study's shared controller (``task.transfer: shared``): making
the job's update the study's next version, merged onto any version that landed while
it trained (the version a job starts from is downloaded by
:func:`adworker.sources.fetch_shared`).

The server keeps only a pointer (``POST /trials/{id}/shared-controller`` is a
compare-and-set on the version); the merging is done here, where the weights can be
read (:func:`adworker.shared_weights.merge`): an update that finds the study moved on
is applied onto the current version, so two workers updating at once lose nothing
(docs/worker.md, "A shared controller").
"""

from __future__ import annotations

import logging

from adclient.client import Client
from adclient.errors import ApiError, Conflict, Forbidden, Unauthorized
from adclient.schemas import SHARED_ARTIFACT, Job, SharedVersion
from adworker import shared_weights

log = logging.getLogger("adworker")

MAX_MERGES = 8
"""Versions an update is merged onto before it is given up (each needs another update
to land between this worker's download and its compare-and-set)."""


def advance_shared(
    client: Client, job: Job, *, worker_id: str, mine: bytes, start: bytes, label: str
) -> int | None:
    """Make ``mine`` (already uploaded as the trial's ``SHARED_ARTIFACT``, trained from
    ``start``) the study's next version; the version it became, or None when it was not
    taken (reason logged: a lost lease, a refused upload, too many updates in between).

    A study that moved on: ``current + (mine - start)`` (the actor ``mine``'s where the
    design carried the critic alone) is uploaded in its place and
    offered on the current version, again until it lands. A current version that does
    not load is replaced by ``mine`` itself. A refused token raises (``Unauthorized``,
    ``Forbidden``): the worker stops."""
    base = job.shared.version if job.shared is not None else None
    try:
        own, started = shared_weights.decode(mine), shared_weights.decode(start)
    except shared_weights.SharedWeightsError as error:
        log.error("%s: its shared-controller update does not load (%s): not offered", label, error)
        return None
    for _ in range(MAX_MERGES):
        try:
            taken = client.advance_shared(job.trial_id, worker_id=worker_id, base_version=base)
        except (Unauthorized, Forbidden):
            raise
        except Conflict as exc:
            current = _current(client, job, label)
            if current is None or current.version == base:
                log.warning("%s: shared-controller update not taken (%s)", label, exc)
                return None
            if current.trial_id == job.trial_id:  # taken; the answer was lost
                return current.version
            try:
                merged = _merged(
                    client,
                    current.trial_id,
                    current.artifact,
                    started,
                    own,
                    actor_of_mine=job.task.shared_carries == "critic",
                )
                client.put_artifact(
                    job.trial_id,
                    SHARED_ARTIFACT,
                    merged,
                    "application/octet-stream",
                    worker_id=worker_id,
                )
            except (Unauthorized, Forbidden):
                raise
            except ApiError as error:
                log.warning("%s: shared-controller update not merged (%s)", label, error)
                return None
            log.info(
                "%s: shared controller moved on to version %d: update merged onto it",
                label,
                current.version,
            )
            base = current.version
        except ApiError as exc:
            log.warning("%s: shared-controller update not taken (%s)", label, exc)
            return None
        else:
            log.info("%s: shared controller now at version %d", label, taken.version)
            return taken.version
    log.warning("%s: shared-controller update given up after %d merges", label, MAX_MERGES)
    return None


def _current(client: Client, job: Job, label: str) -> SharedVersion | None:
    try:
        return client.shared_controller(job.study_id)
    except ApiError as exc:
        log.warning("%s: shared controller not read (%s)", label, exc)
        return None


def _merged(
    client: Client,
    trial_id: int,
    artifact: str,
    started: shared_weights.Weights,
    own: shared_weights.Weights,
    *,
    actor_of_mine: bool,
) -> bytes:
    """``current + (own - started)`` for the version in ``trial_id``'s ``artifact`` (the
    actor ``own``'s with ``actor_of_mine``: ``shared_weights.merge``); ``own`` where that
    version does not load or fit."""
    try:
        current = shared_weights.decode(client.get_artifact(trial_id, artifact))
        merged = shared_weights.merge(current, started, own, actor_of_mine=actor_of_mine)
        return shared_weights.encode(merged)
    except shared_weights.SharedWeightsError as error:
        log.warning("shared controller of trial %s does not merge (%s): replaced", trial_id, error)
        return shared_weights.encode(own)
