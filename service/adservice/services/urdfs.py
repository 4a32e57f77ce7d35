"""A template study's trials: each one's URDF is expanded once, when its params are
fixed (an ask, a lease's proposal, an enqueue or an added trial), and stored; reads and
workers get the stored text (``adservice.robots``, ``Job.urdf``).

Every expansion runs in the expansion pool (``adservice.expansions``), never in a request
thread or a database transaction: a place is taken before the trials are written (a full
pool is a 503 that stores nothing), the expansion runs after, and one short write stores
the URDFs. A trial whose params the template does not expand at is failed with the
template's message (its proposer learns from it, no worker gets it); an enqueued one is
refused (422). Studies of other spaces pass through untouched.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable, Sequence
from functools import partial
from typing import Any, Protocol

from adclient.schemas import Job, Trial, TrialAdd, TrialState
from adservice.db import Database
from adservice.errors import InvalidError
from adservice.expansions import Expansion, ExpansionPool, Place, expand_each
from adservice.repository import urdfs as urdf_repo
from adservice.services.configs import StudyConfigs


class Proposing(Protocol):
    """What expanding a study's new trials needs: ``services.trials.Proposing``."""

    @property
    def db(self) -> Database: ...

    @property
    def configs(self) -> StudyConfigs: ...

    @property
    def expansions(self) -> ExpansionPool: ...


async def template_of(proposing: Proposing, study_id: int) -> str | None:
    """The study's template; None for a study of another space (from the cached
    configuration: a dictionary lookup on the ask hot path)."""
    config = proposing.configs.cached(study_id)
    if config is None:
        config = await proposing.db.run(partial(proposing.configs.get, study_id))
    return config.space["template"] if config.space.get("type") == "template" else None


async def with_urdfs(
    proposing: Proposing, *, study_id: int, fix: Callable[[], Awaitable[list[Trial]]]
) -> list[Trial]:
    """The trials ``fix`` writes (an ask), a template study's with their URDFs stored:
    those that do not expand are answered failed."""
    template = await template_of(proposing, study_id)
    if template is None:
        return await fix()
    with proposing.expansions.admit() as place:
        trials = await fix()
        points = {trial.id: trial.params for trial in trials}
        _, failed = await _expand_new(proposing.db, place, template, points)
    return [failed.get(trial.id, trial) for trial in trials]


async def with_urdf(
    proposing: Proposing, *, study_id: int, lease: Callable[[], Awaitable[Job]]
) -> Job | None:
    """The job ``lease`` leases (a freshly proposed trial), a template study's carrying
    its URDF; None when its params do not expand (the trial is failed: lease another).
    BusyError, before anything is leased, when the expansion pool is full."""
    template = await template_of(proposing, study_id)
    if template is None:
        return await lease()
    with proposing.expansions.admit() as place:
        job = await lease()
        points = {job.trial_id: job.params}
        expansions, failed = await _expand_new(proposing.db, place, template, points)
    if failed:
        return None
    return job.model_copy(update={"urdf": expansions[job.trial_id].urdf})


async def expand_added(
    pool: ExpansionPool, template: str, adds: Sequence[TrialAdd], params: list[dict[str, Any]]
) -> list[Expansion]:
    """Each handed-over trial's expansion, before anything is stored; InvalidError naming
    each one that does not expand but a failed one (an evaluation that failed may be
    one whose params the template does not expand at: it keeps why)."""
    expanded = await pool.run(partial(expand_each, template, params))
    problems = [
        f"{'trial' if len(adds) == 1 else f'trials[{index}]'}.params: the template does not "
        f"expand at them: {expansion.error}"
        for index, (add, expansion) in enumerate(zip(adds, expanded, strict=True))
        if expansion.error is not None and add.state != TrialState.failed
    ]
    if problems:
        raise InvalidError("; ".join(problems), problems=problems)
    return expanded


async def _expand_new(
    db: Database, place: Place, template: str, points: dict[int, dict[str, Any]]
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
    expanded = await place.run(partial(expand_each, template, [points[i] for i in new]))
    fresh = dict(zip(new, expanded, strict=True))

    def store() -> dict[int, Trial]:
        with db.write() as session:
            urdf_repo.store_urdfs(session, expansions=fresh)
            errors = {key: value.error for key, value in fresh.items() if value.error is not None}
            return urdf_repo.fail_unexpanded(session, errors=errors)

    return expansions | fresh, await db.run(store)
