"""Proposing trials: snapshot the history, propose off the database, insert.

Cheap proposers that need no history (random, Sobol) propose inside one short write
transaction. Model-based ones propose with no database lock held (a qEI fit takes a
fraction of a second) under a per-study lock, so concurrent asks of one study each see
the previous one's trials as pending; the routes run them through ``ProposalRunner``
(their own threads, one study at a time), within the server's time and memory budget
per ask (``AskBudget``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
from typing import Any

import numpy as np
from sqlalchemy.orm import Session
from starlette.concurrency import run_in_threadpool

from adclient.objectives import Outcome, OutcomeError
from adclient.schemas import Trial, TrialAdd
from adservice.db import Database
from adservice.errors import ConflictError, ForbiddenError, InvalidError, StudyConfigError
from adservice.expansions import Expansion, ExpansionPool
from adservice.locks import StudyLocks
from adservice.principals import Principal, check_manager
from adservice.proposal_runner import AskBudget, ProposalRunner
from adservice.proposers import DEFAULT_PROPOSER, Proposal, ProposalRequest, Proposer, get_proposer
from adservice.proposers.base import DEGRADED, FidelityHistory, empty_history
from adservice.repository import promotion as promotion_repo
from adservice.repository import quotas as quota_repo
from adservice.repository import studies as study_repo
from adservice.repository import trials as trial_repo
from adservice.repository import urdfs as urdf_repo
from adservice.repository.studies import History
from adservice.services import urdfs
from adservice.services.budget import check_ask_memory
from adservice.services.configs import StudyConfig, StudyConfigs
from adservice.services.proposal_failures import Backoff, failures_recorded


def _request(
    config: StudyConfig,
    *,
    count: int,
    n_issued: int,
    history: History | None,
    budget: AskBudget | None = None,
    max_trials: int | None = None,
) -> ProposalRequest:
    empty = empty_history(config.dim)
    sign = 1.0 if config.maximize else -1.0
    noisy = config.proposer.noisy
    outcomes = config.outcomes
    signs = np.asarray(outcomes.signs)
    objectives = ref_point = slacks = None
    if outcomes.multi:
        values = history.values if history else None
        objectives = values * signs if values is not None else np.zeros((0, outcomes.count))
        if outcomes.reference_point is not None:
            ref_point = np.asarray(outcomes.reference_point) * signs
    if outcomes.constraints:
        slacks = history.slacks if history else None
        if slacks is None:
            slacks = np.zeros((0, len(outcomes.constraints)))
    return ProposalRequest(
        bounds=config.bounds,
        count=count,
        seed=config.proposer.seed,
        n_issued=n_issued,
        X=history.X if history else empty,
        y=sign * history.y if history else np.zeros(0),
        failed=history.failed if history else empty,
        pending=history.pending if history else empty,
        n_initial=config.proposer.n_initial,
        noisy=noisy if noisy is not None else config.task is not None,
        options=config.proposer.options,
        structure=config.search,
        box=config.box,
        spec_polytope=config.polytope,
        seconds=budget.seconds if budget else None,
        memory_bytes=budget.memory_bytes if budget else None,
        objectives=objectives,
        ref_point=ref_point,
        slacks=slacks,
        fidelities=_fidelities(config, history, n_issued=n_issued, max_trials=max_trials),
    )


def _fidelities(
    config: StudyConfig, history: History | None, *, n_issued: int, max_trials: int | None
) -> FidelityHistory | None:
    """A study with ``task.fidelity``: its grid, costs and each trial's fidelity, for the
    multi-fidelity proposer (``adservice.proposers.fidelity``)."""
    fidelity = config.task.fidelity if config.task is not None else None
    if fidelity is None:
        return None
    grid = np.asarray(fidelity.grid(), dtype=np.float64)
    empty = np.zeros(0)
    return FidelityHistory(
        grid=grid,
        cost=np.asarray([fidelity.cost(steps) for steps in grid]),
        observed=history.fidelities if history and history.fidelities is not None else empty,
        pending=(
            history.pending_fidelities
            if history and history.pending_fidelities is not None
            else empty
        ),
        remaining=None if max_trials is None else max(max_trials - n_issued, 0),
    )


def proposer_of(config: StudyConfig) -> Proposer:
    """The study's proposer: the multi-fidelity one for the default proposer of a study
    whose task declares a fidelity (``task.fidelity``), else the one it names."""
    fidelity = config.task.fidelity if config.task is not None else None
    if fidelity is not None and config.proposer.name == DEFAULT_PROPOSER:
        from adservice.proposers.fidelity import FidelityProposer

        return FidelityProposer()
    return get_proposer(config.proposer.name)


def _record(
    db: Database,
    config: StudyConfig,
    *,
    count: int,
    propose: Callable[[int, int], Proposal],
    worker_id: str | None,
    lease_token_id: int | None,
    lease_seconds: float,
    storage_quota: int | None = None,
) -> list[Trial]:
    """In one write transaction: an owner's ask is refused once the owner stores
    ``storage_quota`` bytes; an ask of an unmanaged study takes its queued (enqueued)
    trials first; the rest are ``propose(first_number, n)``'s candidates, under newly
    reserved numbers.

    A worker's lease on PostgreSQL commits that transaction without waiting for its WAL
    flush, so the study's row (locked by the reservation) is free again without that
    wait, and then records the worker as seen in a second transaction, whose commit
    does wait: WAL is flushed in order, so the lease is durable before the worker hears
    of it, and leases' flushes are grouped instead of taken in turns under the row."""
    apart = worker_id is not None and db.dialect == "postgresql"
    trials = _propose_and_insert(
        db,
        config,
        count=count,
        propose=propose,
        worker_id=worker_id,
        lease_token_id=lease_token_id,
        lease_seconds=lease_seconds,
        apart=apart,
        storage_quota=storage_quota,
    )
    if apart:
        assert worker_id is not None
        with db.write() as session:
            trial_repo.record_leased(session, worker_id=worker_id, trial_id=trials[0].id)
    return trials


def _propose_and_insert(
    db: Database,
    config: StudyConfig,
    *,
    count: int,
    propose: Callable[[int, int], Proposal],
    worker_id: str | None,
    lease_token_id: int | None,
    lease_seconds: float,
    apart: bool,
    storage_quota: int | None,
) -> list[Trial]:
    """:func:`_record`'s first transaction (``apart``: committed without waiting for its
    WAL flush, the worker not yet recorded as seen)."""
    with db.write() as session:
        if apart:
            trial_repo.commit_without_flush(session)
        if worker_id is None:  # a lease's studies are within the quota (lease_job)
            quota_repo.check_room(session, study_id=config.study_id, quota=storage_quota)
        claimed: list[Trial] = []
        if worker_id is None and config.task is None:
            claimed = trial_repo.claim_queued(session, study_id=config.study_id, count=count)
        wanted = count - len(claimed)
        if wanted == 0:
            return claimed
        reserved = trial_repo.reserve_for_proposal(session, study_id=config.study_id, count=wanted)
        first = reserved.first
        proposal = propose(first, wanted)
        candidates = config.canonical(proposal.candidates)
        infos = [_in_own_directions(info, config) for info in proposal.info]
        if config.polytope is not None:
            candidates, infos = _inside_spec_constraints(config, candidates, infos)
        _record_fallbacks(session, config.study_id, infos, stored=reserved.fallback_reason)
        return claimed + trial_repo.insert_trials(
            session,
            study_id=config.study_id,
            first_number=first,
            vectors=candidates.tolist(),
            params=[config.params(vector) for vector in candidates],
            infos=infos,
            worker_id=worker_id,
            lease_token_id=lease_token_id,
            lease_seconds=lease_seconds,
            record_worker=not apart,
        )


def _record_fallbacks(
    session: Session, study_id: int, infos: list[dict[str, Any]], *, stored: str | None
) -> None:
    """Count the candidates a budget or a failed model made Sobol points (``DEGRADED``)
    on the study, with the latest reason; an ask whose model proposed clears the reason
    (``stored``: the study's, read by the reservation; nothing to write when None). An
    ask still in its Sobol start records nothing."""
    degraded = [info for info in infos if info.get(DEGRADED)]
    if degraded:
        reason = str(degraded[-1].get("reason", ""))
        study_repo.record_fallbacks(session, study_id=study_id, count=len(degraded), reason=reason)
    elif stored is not None and any(
        not str(info.get("method", "")).startswith("sobol") for info in infos
    ):
        study_repo.record_fallbacks(session, study_id=study_id, count=0, reason=None)


def _inside_spec_constraints(
    config: StudyConfig, candidates: np.ndarray, infos: list[dict[str, Any]]
) -> tuple[np.ndarray, list[dict[str, Any]]]:
    """Candidates that break a spec constraint moved to the nearest design that does not
    (``adservice.feasibility``), their info saying so: whatever the proposer, every
    proposal satisfies the constraints."""
    from adservice.feasibility import into_polytope

    assert config.polytope is not None
    inside, moved = into_polytope(candidates, config.polytope, config.bounds)
    infos = [
        {**info, "spec_constraints": "projected"} if was_moved else info
        for info, was_moved in zip(infos, moved, strict=True)
    ]
    return inside, infos


def _in_own_directions(info: dict[str, Any], config: StudyConfig) -> dict[str, Any]:
    """A candidate's info with the hypervolume reference point in each objective's own
    direction, as the study states its values (proposers see every objective
    maximised)."""
    ref_point = info.get("ref_point")
    if not config.outcomes.multi or not isinstance(ref_point, list):
        return info
    signs = config.outcomes.signs
    return {**info, "ref_point": [float(v) * s for v, s in zip(ref_point, signs, strict=True)]}


def _leading(proposal: Proposal | None, count: int) -> Proposal:
    """``count`` of a proposal made before the write: fewer queued trials were left to
    take than counted when it was made (another server took them) is a conflict."""
    if proposal is None or len(proposal.candidates) < count:
        raise ConflictError("the study's queued trials were taken meanwhile: ask again")
    return Proposal(candidates=proposal.candidates[:count], info=proposal.info[:count])


def proposer_history(session: Session, config: StudyConfig) -> History:
    """The study's trials as its proposer sees them: pruned and paused trials are their
    last values (or left out, as ``pruner.pruned_as`` says), each trial counted once."""
    observed = config.pruner.pruned_as == "last_value"
    fidelity = config.task.fidelity if config.task is not None else None
    history = study_repo.study_history(
        session,
        study_id=config.study_id,
        dim=config.dim,
        pruned_as_observed=observed,
        outcomes=config.outcomes,
        fidelity_max=fidelity.max if fidelity is not None else None,
    )
    if observed and promotion_repo.asha_promotion(config.pruner):
        history = promotion_repo.with_paused(
            session, history=history, study_id=config.study_id, dim=config.dim
        )
    return history


def proposes_instantly(configs: StudyConfigs, study_id: int) -> bool:
    """Whether an ask of this study is only a few short writes: its configuration is
    cached (no read needed) and it is of one design, or its proposer needs no history
    (random, sobol)."""
    config = configs.cached(study_id)
    if config is None or config.proposer_error is not None:
        return config is not None and config.fixed
    return config.fixed or not get_proposer(config.proposer.name).needs_history


def repeats(config: StudyConfig, first: int, count: int) -> Proposal:
    """A study of one design proposes it ``count`` times, no proposer run: the search
    vector is empty, and each info names the trial's own seed (``repeat_seed``)."""
    return Proposal(
        candidates=np.zeros((count, 0)),
        info=[
            {"method": "fixed", "seed": config.repeat_seed(first + offset)}
            for offset in range(count)
        ],
    )


def _history_free(config: StudyConfig) -> Callable[[int, int], Proposal] | None:
    """How a study proposes without its history (its repeats, for a study of one design;
    else a proposer that reads none): ``propose(first_number, n)``; None for a proposer
    that needs the history. StudyConfigError for proposer settings that cannot be used."""
    if config.fixed:
        return partial(repeats, config)
    if config.proposer_error is not None:
        raise StudyConfigError(
            f"study {config.study_id} cannot propose: its proposer settings were stored "
            f"before they were checked and are invalid: {config.proposer_error.detail}",
            problems=config.proposer_error.problems,
        )
    proposer = get_proposer(config.proposer.name)
    if proposer.needs_history:
        return None
    return lambda first, n: proposer.propose(
        _request(config, count=n, n_issued=first, history=None)
    )


def propose_trials(
    db: Database,
    configs: StudyConfigs,
    locks: StudyLocks,
    *,
    study_id: int,
    count: int,
    caller: Principal,
    worker_id: str | None = None,
    lease_seconds: float = 60.0,
    budget: AskBudget | None = None,
    storage_quota: int | None = None,
) -> list[Trial]:
    """New trials of a study: asked by its owner (``worker_id`` None), or proposed for a
    worker's lease (a worker's or an admin's lease from any managed study, a user's only
    from its own); ``budget`` bounds a model-based proposal (an owner's ask beyond its
    memory is refused, naming why); an owner's ask is refused once the owner stores
    ``storage_quota`` bytes (OverQuotaError; a lease's studies are chosen within it)."""
    config = configs.get(study_id)
    if worker_id is None:
        check_manager(
            caller,
            study_id=study_id,
            owner_token_id=config.owner_token_id,
            owner_name=config.owner_name,
        )
    elif caller.leased_owner is not None and caller.leased_owner != config.owner_token_id:
        raise ForbiddenError(
            f"study {study_id} is not this token's: a user token leases only its own "
            "studies' trials"
        )
    lease_token_id = caller.token_id if worker_id is not None else None
    instant = _history_free(config)
    if instant is not None:
        return _record(
            db,
            config,
            count=count,
            propose=instant,
            worker_id=worker_id,
            lease_token_id=lease_token_id,
            lease_seconds=lease_seconds,
            storage_quota=storage_quota,
        )
    proposer = proposer_of(config)
    with locks.hold(db, study_id):
        with db.read() as session:
            study = study_repo.get_study(session, study_id=study_id)
            if worker_id is None:
                quota_repo.check_room(session, study_id=study_id, quota=storage_quota)
            queued = 0
            if worker_id is None and config.task is None:
                queued = trial_repo.count_queued(session, study_id=study_id)
            wanted = max(count - queued, 0)
            trial_repo.check_room(study, count=wanted)
            history = proposer_history(session, config) if wanted else None
        proposal = None
        if history is not None:
            if worker_id is None and budget is not None and budget.memory_bytes is not None:
                check_ask_memory(
                    config,
                    count=wanted,
                    n_issued=study.n_trials,
                    history=history,
                    budget=budget.memory_bytes,
                )
            proposal = proposer.propose(
                _request(
                    config,
                    count=wanted,
                    n_issued=study.n_trials,
                    history=history,
                    budget=budget,
                    max_trials=study.max_trials,
                )
            )
        return _record(
            db,
            config,
            count=count,
            propose=lambda _number, n: _leading(proposal, n),
            worker_id=worker_id,
            lease_token_id=lease_token_id,
            lease_seconds=lease_seconds,
            storage_quota=storage_quota,
        )


async def add_trials(
    proposing: Proposing, *, study_id: int, adds: list[TrialAdd], caller: Principal
) -> list[Trial]:
    """Enqueue trials or add evaluated ones (``TrialAdd``), by the study's owner, while
    the owner stores less than its quota; each one's params are checked against the
    space first, and a template study's expanded (in the expansion pool), so a bad one
    stores nothing."""
    db, configs, quota = proposing.db, proposing.configs, proposing.storage_quota
    template = await urdfs.template_of(proposing, study_id)
    if template is None:
        return await run_in_threadpool(
            lambda: _store_adds(
                db, study_id, adds, _checked_adds(configs, study_id, adds, caller), quota
            )
        )
    checked = await run_in_threadpool(_checked_adds, configs, study_id, adds, caller)

    def within_quota() -> None:
        with db.read() as session:
            quota_repo.check_room(session, study_id=study_id, quota=quota)

    await db.run(within_quota)  # before the expansions, which the quota would refuse
    expanded = await urdfs.expand_added(proposing, study_id, template, adds, checked.params)
    return await run_in_threadpool(_store_adds, db, study_id, adds, checked, quota, expanded)


@dataclass(frozen=True)
class _CheckedAdds:
    vectors: list[list[float]]
    params: list[dict[str, Any]]
    """Each one's params as its trial keeps them."""
    outcomes: list[Outcome | None]


def _checked_adds(
    configs: StudyConfigs, study_id: int, adds: list[TrialAdd], caller: Principal
) -> _CheckedAdds:
    config = configs.get(study_id)
    check_manager(
        caller,
        study_id=study_id,
        owner_token_id=config.owner_token_id,
        owner_name=config.owner_name,
    )
    vectors: list[list[float]] = []
    kept: list[dict[str, Any]] = []
    outcomes: list[Outcome | None] = []
    problems: list[str] = []
    for index, add in enumerate(adds):
        where = "trial" if len(adds) == 1 else f"trials[{index}]"
        try:
            vector = config.canonical(config.vector(add.params)[None, :])[0]
            kept.append(config.given(add.params, vector))
            vectors.append(vector.tolist())
        except ValueError as error:
            problems.append(f"{where}.params: {error}")
        outcomes.append(None)
        if add.state == "complete":
            try:
                outcomes[-1] = config.outcomes.outcome(
                    value=add.value, values=add.values, metrics=add.metrics
                )
            except OutcomeError as error:
                problems.append(f"{where}.{error}")
    if problems:
        raise InvalidError("; ".join(problems), problems=problems)
    return _CheckedAdds(vectors, kept, outcomes)


def _store_adds(
    db: Database,
    study_id: int,
    adds: list[TrialAdd],
    checked: _CheckedAdds,
    storage_quota: int | None,
    expanded: list[Expansion] | None = None,
) -> list[Trial]:
    """The new ones stored in one write (with their URDFs, ``expanded``, for a template
    study), unless the owner stores ``storage_quota`` bytes; with ``skip_if_exists``, an
    existing trial in a new one's place."""
    vectors, kept, outcomes = checked.vectors, checked.params, checked.outcomes
    with db.write() as session:
        quota_repo.check_room(session, study_id=study_id, quota=storage_quota)
        existing: dict[tuple[float, ...], Trial] = {}
        if any(add.skip_if_exists for add in adds):
            existing = trial_repo.trials_of_vectors(session, study_id=study_id, vectors=vectors)
        new: list[int] = []
        repeats: dict[int, int] = {}  # index -> the earlier new one of this body it repeats
        first_of: dict[tuple[float, ...], int] = {}
        for index, (add, vector) in enumerate(zip(adds, vectors, strict=True)):
            key = tuple(vector)
            if add.skip_if_exists and key in existing:
                continue
            if add.skip_if_exists and key in first_of:
                repeats[index] = first_of[key]
                continue
            first_of.setdefault(key, index)
            new.append(index)
        added: list[Trial] = []
        if new:
            first = trial_repo.reserve_numbers(session, study_id=study_id, count=len(new))
            added = trial_repo.add_trials(
                session,
                study_id=study_id,
                first_number=first,
                vectors=[vectors[index] for index in new],
                params=[kept[index] for index in new],
                adds=[adds[index] for index in new],
                outcomes=[outcomes[index] for index in new],
            )
        if expanded is not None:
            urdf_repo.store_urdfs(
                session,
                expansions={trial.id: expanded[i] for i, trial in zip(new, added, strict=True)},
            )
    by_index = dict(zip(new, added, strict=True))
    return [
        by_index.get(repeats.get(index, index)) or existing[tuple(vector)]
        for index, vector in enumerate(vectors)
    ]


@dataclass(frozen=True)
class Proposing:
    """What proposing needs, held once per process: one dependency for the hot routes
    (each FastAPI dependency costs a resolution per request)."""

    db: Database
    configs: StudyConfigs
    locks: StudyLocks
    runner: ProposalRunner
    backoff: Backoff = field(default_factory=Backoff)
    expansions: ExpansionPool = field(default_factory=ExpansionPool)
    storage_quota: int | None = None
    """The bytes one owner's studies may store (``AD_OWNER_STORAGE_BYTES``); None: no
    quota."""


async def ask_trials(
    proposing: Proposing, *, study_id: int, count: int, caller: Principal
) -> list[Trial]:
    """An owner's ask: a history-free proposer's few writes run where short writes run
    (``Database.run``); model fitting runs in the proposal threads once the study's turn
    comes, so it never holds a request thread."""

    def propose() -> list[Trial]:
        with failures_recorded(proposing.db, proposing.backoff, study_id=study_id):
            return propose_trials(
                proposing.db,
                proposing.configs,
                proposing.locks,
                study_id=study_id,
                count=count,
                caller=caller,
                budget=proposing.runner.budget,
                storage_quota=proposing.storage_quota,
            )

    async def asked() -> list[Trial]:
        if proposes_instantly(proposing.configs, study_id):
            return await proposing.db.run(propose)
        return await proposing.runner.run(study_id, propose)

    return await urdfs.with_urdfs(proposing, study_id=study_id, fix=asked)
