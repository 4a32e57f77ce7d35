"""A template study's trials: each one's URDF is expanded once, when its params are
fixed (an ask, a lease's proposal, an enqueue or an added trial), checked, and stored;
reads and workers get the stored text (``adservice.robots``, ``Job.urdf``).

Every expansion runs in the expansion pool (``adservice.expansions``), never in a request
thread or a database transaction: a place is taken before the trials are written (a full
pool is a 503 that stores nothing), the expansion runs after, and one short write stores
the URDFs. Each expansion is checked where it runs as a study's creation checks its
template (a robot the worker builds, with the links its task looks up, within
``AD_MAX_URDF_BYTES``), a batch's together within ``AD_MAX_ASK_URDF_BYTES``, and none is
kept once the study's reach ``AD_MAX_STUDY_URDF_BYTES`` (the one that reaches it is). A
trial whose expansion fails these is failed with the reason (its proposer learns from
it, no worker gets it); an enqueued one is refused (422). A study that stores its limit
gets no new trials: its ask is a 409 and leases skip it.

A study whose expansion fails, or keeps a worker's lease waiting past
``AD_LEASE_EXPAND_SECONDS``, backs off as after a failed proposal (its
``proposal_retry_at``, doubled with each such expansion in a row; a clean one resets
it): leases skip it meanwhile. A lease does not wait longer than that: the slow
expansion goes on in the background, its trial back in the queue, and the lease serves
another study. Studies of other spaces pass through untouched.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Awaitable, Callable, Coroutine, Sequence
from datetime import timedelta
from functools import partial
from typing import Any, Protocol, TypeVar

from adclient.schemas import Job, TaskConfig, Trial, TrialAdd, TrialState
from adclient.templates import EXPAND_SECONDS
from adservice.db import Database
from adservice.errors import ConflictError, InvalidError, ProposalFailedError
from adservice.expansions import Checks, Expansion, ExpansionPool, Place, UrdfLimits, expand_each
from adservice.models import utcnow
from adservice.repository import quotas as quota_repo
from adservice.repository import urdfs as urdf_repo
from adservice.services.configs import StudyConfig, StudyConfigs
from adservice.services.proposal_failures import MAX_ERROR_CHARS, Backoff

log = logging.getLogger("adservice")

T = TypeVar("T")

_BACKGROUND: set[asyncio.Future[Any]] = set()
"""Leases' expansions under way (also those a lease stopped waiting for)."""


class Proposing(Protocol):
    """What expanding a study's new trials needs: ``services.trials.Proposing``."""

    @property
    def db(self) -> Database: ...

    @property
    def configs(self) -> StudyConfigs: ...

    @property
    def expansions(self) -> ExpansionPool: ...

    @property
    def backoff(self) -> Backoff: ...


async def _config(proposing: Proposing, study_id: int) -> StudyConfig:
    """The study's cached configuration (a dictionary lookup on the ask hot path)."""
    config = proposing.configs.cached(study_id)
    if config is None:
        config = await proposing.db.run(partial(proposing.configs.get, study_id))
    return config


async def template_of(proposing: Proposing, study_id: int) -> str | None:
    """The study's template; None for a study of another space."""
    config = await _config(proposing, study_id)
    return config.space["template"] if config.space.get("type") == "template" else None


async def owner_of(proposing: Proposing, study_id: int) -> int | None:
    """The token id of the study's owner, whose share of the expansion pool its
    expansions take (None: an ownerless study's, not counted)."""
    return (await _config(proposing, study_id)).owner_token_id


async def with_urdfs(
    proposing: Proposing, *, study_id: int, fix: Callable[[], Awaitable[list[Trial]]]
) -> list[Trial]:
    """The trials ``fix`` writes (an ask), a template study's with their URDFs stored:
    those that do not expand, or whose URDFs fail the checks, are answered failed.
    ConflictError, before anything is written, once the study stores its limit."""
    template = await template_of(proposing, study_id)
    if template is None:
        return await fix()
    checks = await _checks(proposing, study_id)
    with proposing.expansions.admit(await owner_of(proposing, study_id)) as place:
        trials = await fix()
        points = {trial.id: trial.params for trial in trials}
        _, failed = await _expand_new(proposing.db, place, template, points, checks)
    if failed:
        await _back_off(proposing, study_id, _failure(failed))
    else:
        proposing.expansions.failing.pop(study_id, None)
    return [failed.get(trial.id, trial) for trial in trials]


async def with_urdf(
    proposing: Proposing, *, study_id: int, lease: Callable[[], Awaitable[Job]]
) -> Job | None:
    """The job ``lease`` leases (a freshly proposed trial), a template study's carrying
    its URDF; None when its expansion fails (the trial is failed, the study backs off:
    lease another). BusyError, before anything is leased, when the expansion pool is
    full; ConflictError when the study stores its limit, and, once the lease has
    waited ``AD_LEASE_EXPAND_SECONDS``, a ProposalFailedError (the caller gives the
    trial back to the queue) while the expansion goes on and stores its URDF."""
    template = await template_of(proposing, study_id)
    if template is None:
        return await lease()
    checks = await _checks(proposing, study_id)
    pool = proposing.expansions
    place = pool.admit(await owner_of(proposing, study_id))
    try:
        job = await lease()
    except BaseException:
        place.__exit__(None, None, None)
        raise
    points = {job.trial_id: job.params}
    expanding = asyncio.ensure_future(
        _holding(place, _expand_new(proposing.db, place, template, points, checks))
    )
    _BACKGROUND.add(expanding)  # kept until it ends, whether or not the lease waits
    expanding.add_done_callback(_finished)
    try:
        expansions, failed = await asyncio.wait_for(
            asyncio.shield(expanding), pool.limits.lease_seconds
        )
    except TimeoutError:
        waited = pool.limits.lease_seconds
        detail = await _back_off(
            proposing,
            study_id,
            f"its template's expansion at trial {job.trial_id}'s params took over {waited:g} s "
            "(AD_LEASE_EXPAND_SECONDS): the trial waits in the queue while it expands",
            expanding_for=EXPAND_SECONDS + 1 - waited,
        )
        telling = asyncio.ensure_future(_tell_failure_when_known(proposing, study_id, expanding))
        _BACKGROUND.add(telling)
        telling.add_done_callback(_finished)
        raise ProposalFailedError(detail) from None
    if failed:
        await _back_off(proposing, study_id, _failure(failed))
        return None
    pool.failing.pop(study_id, None)
    return job.model_copy(update={"urdf": expansions[job.trial_id].urdf})


async def expand_added(
    proposing: Proposing,
    study_id: int,
    template: str,
    adds: Sequence[TrialAdd],
    params: list[dict[str, Any]],
) -> list[Expansion]:
    """Each handed-over trial's expansion, checked, before anything is stored;
    InvalidError naming each one that fails but a failed one (an evaluation that failed
    may be one whose params the template does not expand at: it keeps why);
    ConflictError once the study stores its limit."""
    checks = await _checks(proposing, study_id)
    expanded = await proposing.expansions.run(
        partial(expand_each, template, params, checks), await owner_of(proposing, study_id)
    )
    problems = [
        f"{'trial' if len(adds) == 1 else f'trials[{index}]'}.params: the template does not "
        f"expand at them: {expansion.error}"
        for index, (add, expansion) in enumerate(zip(adds, expanded, strict=True))
        if expansion.error is not None and add.state != TrialState.failed
    ]
    if problems:
        raise InvalidError("; ".join(problems), problems=problems)
    return expanded


async def _checks(proposing: Proposing, study_id: int) -> Checks:
    """What the study's new expansions are checked for: the links its task looks up,
    the server's byte limits and the room left under the study's (ConflictError when
    none is left)."""
    limits = proposing.expansions.limits
    db = proposing.db

    def stored() -> int:
        with db.read() as session:
            return quota_repo.study_urdf_bytes(session, study_id=study_id)

    stores = await db.run(stored)
    if stores >= limits.study_bytes:
        raise ConflictError(_study_full(study_id, stores, limits))
    config = proposing.configs.cached(study_id)
    if config is None:
        config = await db.run(partial(proposing.configs.get, study_id))
    return Checks(
        links=task_links(config.task),
        per_urdf=limits.per_urdf(),
        together=limits.per_ask(),
        room=limits.study_room(stores),
    )


def task_links(task: TaskConfig | None) -> tuple[tuple[str, str], ...]:
    """The ``(option, link)`` pairs a study's task looks up in its robot; none for an
    external task, or a stored one no installed plugin reads (its jobs say why)."""
    if task is None or task.external:
        return ()
    from adclient.plugins import catalogue

    try:
        options = catalogue().task(task.name).options.model_validate(task.options)
        return tuple(options.link_names())
    except Exception:
        return ()


def _study_full(study_id: int, stores: int, limits: UrdfLimits) -> str:
    return (
        f"study {study_id} stores {stores:,} bytes of URDFs, the limit of "
        f"{limits.study_bytes:,} bytes per study (AD_MAX_STUDY_URDF_BYTES): no new trial "
        "is made for it"
    )


def _failure(failed: dict[int, Trial]) -> str:
    trial = failed[min(failed)]
    return f"trial {trial.id}: {trial.message}"


async def _back_off(
    proposing: Proposing, study_id: int, error: str, *, expanding_for: float = 0.0
) -> str:
    """Record that the study's expansion failed or ran slow (one more in a row): leases
    skip it for its backoff, after ``expanding_for`` seconds that an expansion still
    running may take. Returns the failure as an answer states it."""
    pool, backoff = proposing.expansions, proposing.backoff
    failures = pool.failing[study_id] = pool.failing.get(study_id, 0) + 1
    delay = min(backoff.max_seconds, backoff.seconds * 2.0 ** min(failures - 1, 64))
    retry_at = utcnow() + timedelta(seconds=delay + max(expanding_for, 0.0))
    text = f"study {study_id}: {error}"[:MAX_ERROR_CHARS]

    def write() -> None:
        with proposing.db.write() as session:
            urdf_repo.back_off(
                session, study_id=study_id, failures=failures, error=text, retry_at=retry_at
            )

    try:
        await proposing.db.run(write)
    except Exception:
        log.warning("study %d: its expansion's backoff was not recorded", study_id, exc_info=True)
    return (
        f"{text} ({failures} in a row; workers' leases skip the study until "
        f"{retry_at:%Y-%m-%d %H:%M:%S} UTC)"
    )


async def _tell_failure_when_known(
    proposing: Proposing,
    study_id: int,
    expanding: asyncio.Future[tuple[dict[int, Expansion], dict[int, Trial]]],
) -> None:
    """Once an expansion a lease stopped waiting for ends, a failure it found replaces
    the study's "took over" error with its reason (the same failure in a row, not one
    more), its backoff counted from then."""
    try:
        _, failed = await asyncio.shield(expanding)
    except Exception:  # said by _finished
        return
    if not failed:
        return
    try:
        pool, backoff = proposing.expansions, proposing.backoff
        failures = pool.failing.get(study_id, 1)
        delay = min(backoff.max_seconds, backoff.seconds * 2.0 ** min(failures - 1, 64))
        retry_at = utcnow() + timedelta(seconds=delay)
        text = f"study {study_id}: {_failure(failed)}"[:MAX_ERROR_CHARS]

        def write() -> None:
            with proposing.db.write() as session:
                urdf_repo.back_off(
                    session, study_id=study_id, failures=failures, error=text, retry_at=retry_at
                )

        await proposing.db.run(write)
    except Exception:
        log.warning("study %d: its expansion's failure was not recorded", study_id, exc_info=True)


async def _holding(place: Place, work: Coroutine[Any, Any, T]) -> T:
    """``work``, the place held until it ends."""
    with place:
        return await work


def _finished(expanding: asyncio.Future[Any]) -> None:
    _BACKGROUND.discard(expanding)
    if not expanding.cancelled() and expanding.exception() is not None:
        log.warning("a lease's template expansion failed: %r", expanding.exception())


async def _expand_new(
    db: Database, place: Place, template: str, points: dict[int, dict[str, Any]], checks: Checks
) -> tuple[dict[int, Expansion], dict[int, Trial]]:
    """Expand the trials (params by id) with no stored URDF (an ask hands out enqueued
    trials, expanded already), store each one's URDF or error, and fail those that did
    not expand. Returns every trial's expansion, and the failed trials, by id."""

    def stored() -> dict[int, Expansion]:
        with db.read() as session:
            return urdf_repo.stored_urdfs(session, trial_ids=list(points))

    expansions = await db.run(stored)
    new = [trial_id for trial_id in points if trial_id not in expansions]
    if not new:
        return expansions, {}
    expanded = await place.run(partial(expand_each, template, [points[i] for i in new], checks))
    fresh = dict(zip(new, expanded, strict=True))

    def store() -> dict[int, Trial]:
        with db.write() as session:
            urdf_repo.store_urdfs(session, expansions=fresh)
            errors = {key: value.error for key, value in fresh.items() if value.error is not None}
            return urdf_repo.fail_unexpanded(session, errors=errors)

    return expansions | fresh, await db.run(store)
