"""Leasing work to workers: a queued trial, else a new one from a managed study."""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from functools import partial

from starlette.concurrency import run_in_threadpool

from adclient.schemas import Job, Trial
from adservice.db import Database
from adservice.errors import BusyError, ConflictError, ProposalFailedError, StudyConfigError
from adservice.principals import Principal
from adservice.repository import leases as lease_repo
from adservice.repository import promotion as promotion_repo
from adservice.repository import urdfs as urdf_repo
from adservice.services import urdfs
from adservice.services.configs import StudyConfigs
from adservice.services.proposal_failures import failures_recorded
from adservice.services.transfer import shared_version, transfer_source
from adservice.services.trials import Proposing, propose_trials, proposes_instantly

log = logging.getLogger("adservice")


async def lease_job(
    proposing: Proposing,
    *,
    worker_id: str,
    caller: Principal,
    lease_seconds: float,
    tasks: Sequence[str] | None = None,
    learners: Sequence[str] | None = None,
) -> Job | None:
    """A queued trial if there is one, else a freshly proposed one from a managed study
    with room; None when there is no work (of ``tasks`` and ``learners``, when given).
    A user token's lease serves only the studies it created (``Principal.leased_owner``),
    a worker's or an admin's every study; studies whose owner stores its storage quota
    (``Proposing.storage_quota``) are skipped, queued trials and new ones alike.
    Paused trials of studies whose budget is spent are ended first (pruned). Leasing a
    queued trial is one short write that never waits for a proposal; a model-based proposal
    runs in the proposal threads, preferring a study with none under way. A study whose
    proposal fails is recorded and skipped (``proposal_failures``): the same lease goes
    on to the next study. The worker is recorded as seen by the write that leases it a
    trial, or by a write of its own when there is no work."""
    db, configs, locks, proposals = (
        proposing.db,
        proposing.configs,
        proposing.locks,
        proposing.runner,
    )
    owner, quota = caller.leased_owner, proposing.storage_quota

    def queued() -> Trial | None:
        with db.write() as session:
            promotion_repo.settle_spent_studies(session)
            row = lease_repo.lease_queued_trial(
                session,
                worker_id=worker_id,
                lease_token_id=caller.token_id,
                lease_seconds=lease_seconds,
                tasks=tasks,
                learners=learners,
                owner=owner,
                storage_quota=quota,
            )
            return Trial.model_validate(row, from_attributes=True) if row else None

    def wanting() -> list[int]:
        with db.read() as session:
            return lease_repo.studies_wanting_trials(
                session, tasks=tasks, learners=learners, owner=owner, storage_quota=quota
            )

    def give_back(trial: Trial) -> None:
        """A leased trial whose job the worker never got goes back to the queue at once,
        its attempt not counted (else it waits out its lease and spends an attempt);
        where even that write fails, the lease expires as usual."""
        try:
            with db.write() as session:
                lease_repo.release_lease(
                    session, trial_id=trial.id, worker_id=worker_id, caller=caller
                )
        except Exception:
            log.exception("trial %s: its lease could not be given back: it expires", trial.id)

    def job_of(trial: Trial) -> Job:
        """The leased trial's job; a failure to make it (stored settings that no longer
        load, a read the database refused) is recorded on the study, whose trials leases
        then skip for its backoff (``failures_recorded``)."""
        with failures_recorded(db, proposing.backoff, study_id=trial.study_id):
            return job_for(db, configs, trial)

    def served(trial: Trial) -> Job | None:
        """The queued trial's job; None when its study cannot make one. Whatever fails,
        the trial goes back to the queue (``give_back``)."""
        try:
            return job_of(trial)
        except Exception as error:
            give_back(trial)
            if isinstance(error, (ProposalFailedError, StudyConfigError)):
                return None
            raise

    trial = await db.run(queued)
    while trial is not None:  # job_for reads (a resume point, a transfer scan): off the loop
        job = await run_in_threadpool(served, trial)
        if job is not None:
            return job
        trial = await db.run(queued)
    for study_id in proposals.free_first(await db.run(wanting)):

        def propose(study_id: int = study_id) -> Trial:
            with failures_recorded(db, proposing.backoff, study_id=study_id):
                (trial,) = propose_trials(
                    db,
                    configs,
                    locks,
                    study_id=study_id,
                    count=1,
                    caller=caller,
                    worker_id=worker_id,
                    lease_seconds=lease_seconds,
                    budget=proposals.budget,
                )
            return trial

        held: list[Trial] = []

        async def leased(
            propose: Callable[[], Trial] = propose,
            study_id: int = study_id,
            held: list[Trial] = held,
        ) -> Job:
            if proposes_instantly(configs, study_id):
                trial = await db.run(propose)
            else:
                trial = await proposals.run(study_id, propose)
            held.append(trial)
            return await run_in_threadpool(job_of, trial)

        try:
            job = await urdfs.with_urdf(proposing, study_id=study_id, lease=leased)
        except Exception as error:
            if held:  # leased, but the job (or its URDF) failed after: not the worker's
                await db.run(partial(give_back, held[0]))
            if isinstance(error, (ConflictError, BusyError)):
                # filled or stopped meanwhile, its proposal failed, or no place to expand
                # its template: the next study
                continue
            raise
        if job is not None:  # None: the template does not expand at its params
            return job

    def idle() -> None:
        with db.write() as session:
            lease_repo.record_idle_worker(
                session, worker_id=worker_id, tasks=tasks, learners=learners
            )

    await db.run(idle)
    return None


def job_for(db: Database, configs: StudyConfigs, trial: Trial) -> Job:
    """The job of a leased trial, read after the lease's write (so the lease never waits
    on it): a promoted trial's resume point while a worker's (``resume_point``); for a
    study with ``task.transfer: nearest``, its source, left out with the reason logged
    when it cannot be chosen (the lease stands: the design trains from scratch); with
    ``shared``, the study's current shared controller; for a template
    study, with its stored URDF (none yet for a trial just proposed: see
    ``urdfs.with_urdf``); for a study of one design, the task with the trial's own seed
    (``StudyConfig.repeat_seed``), so its repeats differ."""
    config = configs.get(trial.study_id)
    assert config.task is not None and trial.lease_expires_at is not None
    task = config.task.at_fidelity(trial.info.get("fidelity"))
    if config.fixed:
        task = task.model_copy(update={"seed": config.repeat_seed(trial.number)})
    transfer = None
    urdf: str | None = None
    if config.space.get("type") == "template":
        with db.read() as session:
            stored = urdf_repo.stored_urdfs(session, trial_ids=[trial.id]).get(trial.id)
        urdf = stored.urdf if stored else None
    resume = None
    if trial.checkpoint is not None:
        with db.read() as session:
            resume = promotion_repo.resume_point(session, trial=trial)
        if resume is None:
            log.warning(
                "trial %s: its checkpoint is no worker's upload of the lease that paused "
                "it: it trains from scratch",
                trial.id,
            )
    shared = None
    if config.task.transfer == "shared":
        shared = shared_version(db, study_id=trial.study_id)
    elif config.task.transfer != "none":
        try:
            transfer = transfer_source(db, trial=trial, config=config)
        except Exception as error:
            log.warning(
                "trial %s: no transfer source (%s: %s): its controller starts from scratch",
                trial.id,
                type(error).__name__,
                error,
            )
    return Job.model_validate(
        {
            "trial_id": trial.id,
            "study_id": trial.study_id,
            "number": trial.number,
            "attempt": trial.attempts,
            "vector": trial.vector,
            "params": trial.params,
            "task": task,
            "space": config.space,
            "representation": config.representation,
            "lease_expires_at": trial.lease_expires_at,
            "pruner": config.pruner,
            "resume": resume,
            "transfer": transfer,
            "shared": shared,
            "urdf": urdf,
        }
    )
