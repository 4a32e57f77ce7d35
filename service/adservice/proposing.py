"""From a study to new trials: snapshot the history, propose off the database, insert.

A study's configuration (space, proposer, representation) never changes after it is
created, so each server keeps it parsed in memory. Cheap proposers that need no
history (random, Sobol) propose inside one short write transaction. Model-based ones
propose with no database lock held (a qEI fit takes a fraction of a second) under a
per-study lock, so concurrent asks of one study each see the previous one's trials as
pending; the routes run them through ``ProposalRunner`` (their own threads, one study
at a time), within the server's time and memory budget per ask (``AskBudget``).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from pydantic import ValidationError

from adclient.design import DesignSpace, Representation
from adclient.schemas import (
    Job,
    ProposerConfig,
    StudyCreate,
    TaskConfig,
    Trial,
    option_problems,
)
from adservice import repository
from adservice.db import Database
from adservice.errors import ConflictError, InvalidError, StudyConfigError
from adservice.locks import StudyLocks
from adservice.models import StudyRow
from adservice.principals import Principal, check_manager
from adservice.proposal_runner import AskBudget, ProposalRunner
from adservice.proposers import (
    Proposal,
    ProposalRequest,
    available,
    get_proposer,
    options_model,
    proposer_class,
)
from adservice.proposers.base import SearchStructure, empty_history
from adservice.repository import History

log = logging.getLogger("adservice")


def check_proposer(config: ProposerConfig) -> None:
    """A known proposer and options it declares; InvalidError naming each problem."""
    if config.name not in available():
        raise InvalidError(
            f"proposer.name: unknown proposer {config.name!r}; "
            f"choose one of {', '.join(available())}"
        )
    model = options_model(config.name)
    try:
        model.model_validate(config.options)
    except ValidationError as error:
        problems = option_problems(error, model, config.name, prefix="proposer.options")
        raise InvalidError("; ".join(problems), problems=problems) from None


@dataclass(frozen=True)
class StudyConfig:
    """The immutable part of a study, parsed once."""

    study_id: int
    maximize: bool
    owner_token_id: int | None
    owner_name: str | None
    proposer: ProposerConfig
    task: TaskConfig | None
    space: dict[str, Any]
    design_space: DesignSpace | None
    representation: Representation | None
    bounds: np.ndarray
    search: SearchStructure | None = None
    """What a design vector's coordinates mean, for proposers that model them."""
    proposer_error: InvalidError | None = None
    """Why the stored proposer settings cannot be used (a study stored before they were
    checked at creation): asking such a study answers 409 naming the problem."""

    @classmethod
    def from_row(cls, row: StudyRow) -> StudyConfig:
        proposer = ProposerConfig.model_validate(row.proposer)
        try:
            check_proposer(proposer)
            proposer_error = None
        except InvalidError as error:
            proposer_error = error
            log.warning("study %d cannot propose: %s", row.id, error.detail)
        representation: Representation | None = None
        design_space: DesignSpace | None = None
        search: SearchStructure | None = None
        if row.representation is not None:
            from adservice.representation import search_structure

            representation = Representation.model_validate(row.representation)
            bounds = np.asarray(representation.bounds, dtype=np.float64)
            design_space = DesignSpace.model_validate(row.space)
            search = search_structure(design_space, representation)
        else:
            params = row.space["params"]
            bounds = np.array([[p["low"] for p in params], [p["high"] for p in params]])
        return cls(
            study_id=row.id,
            maximize=row.direction == "maximize",
            owner_token_id=row.owner_token_id,
            owner_name=row.created_by,
            proposer=proposer,
            task=TaskConfig.model_validate(row.task) if row.task else None,
            space=row.space,
            design_space=design_space,
            representation=representation,
            bounds=bounds,
            search=search,
            proposer_error=proposer_error,
        )

    @property
    def dim(self) -> int:
        return int(self.bounds.shape[1])

    def params(self, vector: np.ndarray) -> dict[str, Any]:
        """What a person reads: box params by name, or the decoded design."""
        if self.representation is None or self.design_space is None:
            names = [p["name"] for p in self.space["params"]]
            return {name: float(x) for name, x in zip(names, vector, strict=True)}
        from adclient.decode import decode, design_params

        return design_params(decode(self.design_space, self.representation, vector.tolist()))


def study_config(db: Database, study_id: int) -> StudyConfig:
    config = db.study_configs.get(study_id)
    if config is None:
        with db.read() as session:
            config = StudyConfig.from_row(repository.get_study(session, study_id=study_id))
        db.study_configs[study_id] = config
    return config


def create_study(
    db: Database, *, body: StudyCreate, owner: Principal, budget: AskBudget | None = None
) -> StudyRow:
    """Check what the schema cannot (the proposer and its options, the representation's
    numbers, an ask's memory within ``budget``), then store the study; InvalidError, with
    nothing stored, otherwise."""
    check_proposer(body.proposer)
    representation = None
    if isinstance(body.space, DesignSpace):
        from adservice.representation import build_representation

        representation = build_representation(body.space).model_dump(mode="json")
        _check_finite(body.space, representation)
        dim = len(representation["bounds"][0])
    else:
        dim = len(body.space.params)
    if budget is not None and budget.memory_bytes is not None:
        _check_options_memory(body.proposer, dim=dim, budget=budget.memory_bytes)
    with db.write() as session:
        return repository.create_study(
            session, body=body, representation=representation, owner=owner
        )


def _non_finite(value: Any, where: str) -> str | None:
    """The path of the first NaN or infinite number in a JSON value, if any."""
    if isinstance(value, float):
        return None if math.isfinite(value) else where
    if isinstance(value, dict):
        items: Any = value.items()
    elif isinstance(value, list):
        items = enumerate(value)
    else:
        return None
    for key, item in items:
        found = _non_finite(item, f"{where}.{key}")
        if found is not None:
            return found
    return None


def _check_finite(space: DesignSpace, representation: dict[str, Any]) -> None:
    """A representation that overflowed cannot decode designs (and PostgreSQL refuses
    to store NaN); the one setting known to do it is a huge ``fusion_margin``."""
    where = _non_finite(representation, "representation")
    if where is None:
        return
    if space.fusion_margin > 0:
        raise InvalidError(
            f"space.design.fusion_margin: {space.fusion_margin:g} is too large: the fused "
            f"distances overflow ({where} is not a finite number); the distances it "
            "separates are between normalised spec vectors, a few units at most"
        )
    raise InvalidError(f"space.design: the search representation overflows ({where})")


def _memory_need(
    config: ProposerConfig,
    *,
    dim: int,
    count: int,
    n_train: int,
    n_pending: int,
    n_failed: int = 0,
) -> Any:
    """The proposer's estimate of an ask's peak memory (``qei.MemoryNeed``), or None
    for proposers whose memory does not grow with their options."""
    estimate = getattr(proposer_class(config.name), "memory_need", None)
    if estimate is None:
        return None
    return estimate(
        config.options,
        dim=dim,
        count=count,
        n_train=n_train,
        n_pending=n_pending,
        n_failed=n_failed,
    )


def _over_budget(need: Any, budget: int) -> str:
    return (
        f"an ask would need {need.describe()}, more than this server allows per ask "
        f"({budget / 2**20:.0f} MB, AD_ASK_MEMORY_MB)"
    )


def _check_options_memory(config: ProposerConfig, *, dim: int, budget: int) -> None:
    """InvalidError naming the option when one point asked of a study with a few
    observations already exceeds the memory budget."""
    need = _memory_need(config, dim=dim, count=1, n_train=2, n_pending=0)
    if need is None or need.bytes <= budget:
        return
    named = need.driver in options_model(config.name).model_fields
    path = f"proposer.options.{need.driver}" if named else "proposer.options"
    advice = f"; lower {need.driver}" if named else ""
    problem = f"{path}: {_over_budget(need, budget)}{advice}"
    raise InvalidError(problem, problems=[problem])


def _check_ask_memory(
    config: StudyConfig, *, count: int, n_issued: int, history: History, budget: int
) -> None:
    """InvalidError naming ``count`` (with the largest count that fits) or the option
    when an ask exceeds the memory budget; one that exceeds it through its history alone
    is left to the proposer, which falls back and says why."""
    proposer = config.proposer
    model_count = count - min(max(proposer.n_initial - n_issued, 0), count)
    if model_count == 0:
        return

    def need(points: int) -> Any:
        return _memory_need(
            proposer,
            dim=config.dim,
            count=points,
            n_train=len(history.y),
            n_pending=len(history.pending),
            n_failed=len(history.failed),
        )

    asked = need(model_count)
    if asked is None or asked.bytes <= budget:
        return
    _check_options_memory(proposer, dim=config.dim, budget=budget)
    if need(1).bytes > budget:
        return
    fits = max(c for c in range(1, model_count) if need(c).bytes <= budget)
    problem = (
        f"count: {_over_budget(asked, budget)}; ask at most {fits + count - model_count} "
        "points at a time"
    )
    raise InvalidError(problem, problems=[problem])


def _request(
    config: StudyConfig,
    *,
    count: int,
    n_issued: int,
    history: History | None,
    budget: AskBudget | None = None,
) -> ProposalRequest:
    empty = empty_history(config.dim)
    sign = 1.0 if config.maximize else -1.0
    noisy = config.proposer.noisy
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
        seconds=budget.seconds if budget else None,
        memory_bytes=budget.memory_bytes if budget else None,
    )


def _record(
    db: Database,
    config: StudyConfig,
    *,
    count: int,
    propose: Callable[[int], Proposal],
    worker_id: str | None,
    lease_token_id: int | None,
    lease_seconds: float,
) -> list[Trial]:
    """Reserve trial numbers and store what ``propose(first_number)`` returns, in one
    write transaction (a bare connection unless a worker's lease is recorded too)."""
    transaction = db.write() if worker_id else db.write_connection()
    with transaction as handle:
        first = repository.reserve_numbers(handle, study_id=config.study_id, count=count)
        proposal = propose(first)
        candidates = np.clip(proposal.candidates, config.bounds[0], config.bounds[1])
        return repository.insert_trials(
            handle,
            study_id=config.study_id,
            first_number=first,
            vectors=candidates.tolist(),
            params=[config.params(vector) for vector in candidates],
            infos=proposal.info,
            worker_id=worker_id,
            lease_token_id=lease_token_id,
            lease_seconds=lease_seconds,
        )


def proposes_instantly(db: Database, study_id: int) -> bool:
    """Whether an ask of this study is only a few short writes: its configuration is
    cached (no read needed) and its proposer needs no history (random, sobol)."""
    config = db.study_configs.get(study_id)
    if config is None or config.proposer_error is not None:
        return False
    return not get_proposer(config.proposer.name).needs_history


def propose_trials(
    db: Database,
    locks: StudyLocks,
    *,
    study_id: int,
    count: int,
    caller: Principal,
    worker_id: str | None = None,
    lease_seconds: float = 60.0,
    budget: AskBudget | None = None,
) -> list[Trial]:
    """New trials of a study: asked by its owner (``worker_id`` None), or proposed for a
    worker's lease (any worker may lease from any managed study); ``budget`` bounds a
    model-based proposal (an owner's ask beyond its memory is refused, naming why)."""
    config = study_config(db, study_id)
    if worker_id is None:
        check_manager(
            caller,
            study_id=study_id,
            owner_token_id=config.owner_token_id,
            owner_name=config.owner_name,
        )
    lease_token_id = caller.token_id if worker_id is not None else None
    if config.proposer_error is not None:
        raise StudyConfigError(
            f"study {study_id} cannot propose: its proposer settings were stored before "
            f"they were checked and are invalid: {config.proposer_error.detail}",
            problems=config.proposer_error.problems,
        )
    proposer = get_proposer(config.proposer.name)
    if not proposer.needs_history:
        return _record(
            db,
            config,
            count=count,
            propose=lambda first: proposer.propose(
                _request(config, count=count, n_issued=first, history=None)
            ),
            worker_id=worker_id,
            lease_token_id=lease_token_id,
            lease_seconds=lease_seconds,
        )
    with locks.hold(db, study_id):
        with db.read() as session:
            study = repository.get_study(session, study_id=study_id)
            repository.check_room(study, count=count)
            history = repository.study_history(session, study_id=study_id, dim=config.dim)
        if worker_id is None and budget is not None and budget.memory_bytes is not None:
            _check_ask_memory(
                config,
                count=count,
                n_issued=study.n_trials,
                history=history,
                budget=budget.memory_bytes,
            )
        proposal = proposer.propose(
            _request(config, count=count, n_issued=study.n_trials, history=history, budget=budget)
        )
        return _record(
            db,
            config,
            count=count,
            propose=lambda _first: proposal,
            worker_id=worker_id,
            lease_token_id=lease_token_id,
            lease_seconds=lease_seconds,
        )


async def lease_job(
    db: Database,
    locks: StudyLocks,
    proposals: ProposalRunner,
    *,
    worker_id: str,
    caller: Principal,
    lease_seconds: float,
    tasks: Sequence[str] | None = None,
) -> Job | None:
    """A queued trial if there is one, else a freshly proposed one from a managed study
    with room; None when there is no work (of ``tasks``, when given). Leasing a queued
    trial is one short write that never waits for a proposal; a model-based proposal
    runs in ``proposals``, preferring a study with none under way."""

    def queued() -> Job | None:
        with db.write() as session:
            row = repository.lease_queued_trial(
                session,
                worker_id=worker_id,
                lease_token_id=caller.token_id,
                lease_seconds=lease_seconds,
                tasks=tasks,
            )
            trial = Trial.model_validate(row, from_attributes=True) if row else None
        return _job(db, trial) if trial else None

    def wanting() -> list[int]:
        with db.read() as session:
            return repository.studies_wanting_trials(session, tasks=tasks)

    job = await db.run(queued)
    if job is not None:
        return job
    for study_id in proposals.free_first(await db.run(wanting)):

        def propose(study_id: int = study_id) -> Job:
            (trial,) = propose_trials(
                db,
                locks,
                study_id=study_id,
                count=1,
                caller=caller,
                worker_id=worker_id,
                lease_seconds=lease_seconds,
                budget=proposals.budget,
            )
            return _job(db, trial)

        try:
            if proposes_instantly(db, study_id):
                return await db.run(propose)
            return await proposals.run(study_id, propose)
        except ConflictError:
            continue  # filled or stopped meanwhile: try the next study
    return None


def _job(db: Database, trial: Trial) -> Job:
    config = study_config(db, trial.study_id)
    assert config.task is not None and trial.lease_expires_at is not None
    return Job.model_validate(
        {
            "trial_id": trial.id,
            "study_id": trial.study_id,
            "number": trial.number,
            "attempt": trial.attempts,
            "vector": trial.vector,
            "params": trial.params,
            "task": config.task,
            "space": config.space,
            "representation": config.representation,
            "lease_expires_at": trial.lease_expires_at,
        }
    )
