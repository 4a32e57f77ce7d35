"""Creating a study (the checks its schema cannot make, then one write) and deleting one."""

from __future__ import annotations

import math
from collections.abc import Awaitable, Callable
from functools import partial
from typing import Any

import numpy as np
from starlette.concurrency import run_in_threadpool

from adclient.design import DesignSpace
from adclient.designs import Representation
from adclient.devices import device_problem
from adclient.overlaps import space_overlaps
from adclient.polytope import spec_polytope
from adclient.schemas import ProposerConfig, StudyCreate, TemplateSpace
from adclient.similarity import similarity_steps
from adclient.templates import ByteLimit
from adservice.artifacts import ArtifactStore
from adservice.creations import CreationPool
from adservice.db import Database
from adservice.errors import InvalidError
from adservice.expansions import ExpansionPool
from adservice.models import StudyRow
from adservice.principals import Principal
from adservice.proposal_runner import AskBudget
from adservice.proposers import available, proposer_class
from adservice.repository import edits as edit_repo
from adservice.repository import studies as study_repo
from adservice.services.budget import check_options_memory
from adservice.services.configs import check_proposer

SIMILARITY_STEPS_PER_SECOND = 1_000_000
"""Steps of the structures' similarity (``adclient.similarity.similarity_steps``) a
creation's second allows: where it was measured (one core of the 2-core development
machine, busy) a bounded step took 0.03 to 0.5 us (trees of 5 to 32 links: paths,
stars, random), so the similarity takes at most about half of AD_CREATE_SECONDS and
leaves the rest to the fusion and the embedding."""


async def create_study(
    db: Database,
    expansions: ExpansionPool,
    creations: CreationPool,
    *,
    body: StudyCreate,
    owner: Principal,
    budget: AskBudget | None = None,
    disconnected: Callable[[], Awaitable[bool]] | None = None,
) -> StudyRow:
    """Check what the schema cannot (the proposer and its options; a design space's
    cost, then its representation and the numbers it gives, in a child of the creation
    pool; an ask's memory within ``budget``; a template's expansions last, in the
    expansion pool), then store the study; InvalidError (or BusyError when a pool is
    full, ClientGoneError once ``disconnected()``), with nothing stored, otherwise."""
    await run_in_threadpool(_checked, body, creations.budget.seconds)
    share = owner.token_id if owner.checked else None  # whose share of the pools it takes
    representation = None
    if isinstance(body.space, DesignSpace):
        representation = await creations.run(
            space_representation, body.space, disconnected=disconnected, owner=share
        )
        dim = len(representation["bounds"][0])
    else:
        dim = len(body.space.params)
    await run_in_threadpool(_check_memory, body, dim, budget)
    if isinstance(body.space, TemplateSpace):
        await expansions.run(partial(_check_template, body, expansions.limits.per_urdf()), share)

    if isinstance(body.space, DesignSpace) and body.space.allow_overlaps is None:
        # stored as said: a study stored before the overlap check keeps null, unchecked
        body = body.model_copy(
            update={"space": body.space.model_copy(update={"allow_overlaps": False})}
        )

    def store() -> StudyRow:
        with db.write() as session:
            return study_repo.create_study(
                session, body=body, representation=representation, owner=owner
            )

    return await db.run(store)


def _checked(body: StudyCreate, seconds: float) -> None:
    """The checks that take no child: the proposer's, a template's task, and a design
    space's creation rules and similarity cost within ``seconds`` (AD_CREATE_SECONDS).
    A study of one design runs no proposer: only that its settings load is checked."""
    check_proposer(body.proposer)
    if not body.space.searches_nothing:
        _check_proposer_device(body.proposer)
        _check_proposer_outcomes(body)
        _check_large_history(body)
    if isinstance(body.space, DesignSpace):
        try:
            body.space.check_at_creation()
        except ValueError as error:
            raise InvalidError(f"space: {error}") from None
        _check_similarity_cost(body.space, seconds)
    elif isinstance(body.space, TemplateSpace):
        _check_template_task(body)


def _check_memory(body: StudyCreate, dim: int, budget: AskBudget | None) -> None:
    """One point asked of the study fits the ask's memory budget, by its estimate."""
    if body.space.searches_nothing or budget is None or budget.memory_bytes is None:
        return
    check_options_memory(
        body.proposer, dim=dim, budget=budget.memory_bytes, outcomes=body.outcomes()
    )


def _check_similarity_cost(space: DesignSpace, seconds: float) -> None:
    """The structures' similarity matrix fits the creation's time, by the bound on its
    steps (``adclient.similarity.similarity_steps``), before any of it is computed."""
    structures = space.tree_structures()
    if len(structures) < 2 or space.encoding == "onehot":
        return
    steps = similarity_steps(structures)
    allowed = int(seconds * SIMILARITY_STEPS_PER_SECOND)
    if steps > allowed:
        raise InvalidError(
            f"space.structures: the similarity of {len(structures)} structures of up to "
            f"{max(len(edges) + 1 for edges in structures)} links takes up to {steps:.3g} "
            f"steps, more than the {allowed:.3g} that fit in the limit of {seconds:g} s "
            "(AD_CREATE_SECONDS): list fewer structures, or structures of fewer links"
        )


WARM_UP_SPACE: dict[str, Any] = {
    "type": "design",
    "parts": {"link": {"length": {"low": 0.1, "high": 0.5}, "radius": 0.04, "mass": 1.0}},
    "instances": [{"name": name, "part": "link"} for name in "abc"],
    "structures": [[["a", "b"], ["b", "c"]], [["a", "b"], ["a", "c"]]],
    "spec_constraints": [{"terms": {"a.length": 1.0, "b.length": 1.0}, "op": "<=", "bound": 0.9}],
}
"""A space whose representation takes every path a new space's does (similarity,
fusion, MDS, a spec constraint), in a few milliseconds."""


def warm_up() -> None:
    """Run the creation checks once on ``WARM_UP_SPACE``, so that what they load and
    cache at their first run (about 15 ms) is there already in a process forked after."""
    space_representation(DesignSpace.model_validate(WARM_UP_SPACE))


def space_representation(space: DesignSpace) -> dict[str, Any]:
    """The search representation of a new design space, checked (some design of it can
    be built, unless it allows overlaps; its numbers finite, its spec constraints
    satisfiable), as stored: the creation pool's work, in a child."""
    from adservice.representation import build_representation

    if not space.allow_overlaps:
        reason = space_overlaps(space)
        if reason is not None:
            raise InvalidError(f"space: {reason}")
    built = build_representation(space)
    representation = built.model_dump(mode="json")
    _check_finite(space, representation)
    _check_spec_constraints(space, built)
    return representation


def _check_proposer_device(config: ProposerConfig) -> None:
    """A study whose model asks for a device this server's torch cannot use is refused:
    accepted, its every ask would fall back to Sobol points."""
    device = config.options.get("device")
    problem = device_problem(device) if isinstance(device, str) else None
    if problem is not None:
        raise InvalidError(
            f"proposer.options.device: {device} cannot be used on this server: {problem}; "
            "leave device out (the server's AD_PROPOSER_DEVICE) or set it to cpu"
        )


def _check_large_history(body: StudyCreate) -> None:
    """``large_history: trust-region`` is a model of a continuous box with one outcome
    (``adservice.proposers.trust_region``): on any other study it would be ignored, so it
    is refused, naming why."""
    if body.proposer.options.get("large_history") != "trust-region":
        return
    outcomes = body.outcomes()
    if isinstance(body.space, DesignSpace):
        reason = "a design space (its structures are discrete)"
    elif any(p.type != "float" or p.step is not None for p in body.space.params):
        reason = "a space with int, stepped or categorical params"
    elif outcomes.count + len(outcomes.constraints) > 1:
        reason = "a study of several objectives or with outcome constraints"
    else:
        return
    raise InvalidError(
        f"proposer.options.large_history: trust-region is for a box of continuous params "
        f"with one objective and no outcome constraints, not {reason}; leave it out (the "
        "subset) or set it to subset"
    )


def _check_template_task(body: StudyCreate) -> None:
    """A task that builds its robot from a template (its plugin takes one)."""
    if body.task is not None and not body.task.external:
        from adclient.plugins import catalogue

        if not catalogue().task(body.task.name).templates:
            raise InvalidError(
                f"task.name: task {body.task.name!r} builds its robot from a design space "
                "(its plugin takes no template): use space.type design, or a task that "
                "takes templates (stand-up, lift-highest, walk-forward, diagonal-gesture)"
            )


def _check_template(body: StudyCreate, max_bytes: ByteLimit) -> None:
    """The template expands to a robot a worker can build, having the links its task
    looks up, within ``max_bytes`` (in a child process: ``adclient.templates``)."""
    from adclient.templates import TemplateError, check_template

    assert isinstance(body.space, TemplateSpace)
    links = body.task.links_looked_up() if body.task is not None else []
    try:
        check_template(body.space.template, body.space.params, links, max_bytes=max_bytes)
    except TemplateError as error:
        raise InvalidError(f"space.template: {error}") from None


def _check_proposer_outcomes(body: StudyCreate) -> None:
    """A study of several objectives, or with constraints, needs a proposer that reads
    them (``Proposer.multi_objective``, ``Proposer.constrained``)."""
    outcomes = body.outcomes()
    needs = [
        ("multi_objective", "several objectives", outcomes.multi),
        ("constrained", "outcome constraints", bool(outcomes.constraints)),
    ]
    for attribute, what, needed in needs:
        if not needed:
            continue
        able = [name for name in available() if getattr(proposer_class(name), attribute)]
        if body.proposer.name not in able:
            raise InvalidError(
                f"proposer.name: {body.proposer.name!r} does not handle {what}; "
                f"choose one of {', '.join(able)}"
            )


def delete_study(
    db: Database, store: ArtifactStore, *, study_id: int, caller: Principal, force: bool
) -> None:
    """Delete the study's rows in one write, then its files: a crash in between leaves
    files no row points at (never served), never a row without its file."""
    with db.write() as session:
        paths = edit_repo.delete_study(session, study_id=study_id, caller=caller, force=force)
    for path in paths:
        store.discard(path)
    store.remove_study(study_id)


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


def _check_spec_constraints(space: DesignSpace, representation: Representation) -> None:
    """Spec constraints some design in the search box satisfies (else no ask could)."""
    from adservice.feasibility import check_satisfiable

    polytope = spec_polytope(space, representation)
    if polytope is None:
        return
    try:
        check_satisfiable(polytope, np.asarray(representation.bounds, dtype=np.float64))
    except ValueError as error:
        raise InvalidError(f"space.spec_constraints: {error}") from None


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
