"""The robot behind a trial: its decoded design, its URDF, and where adworker's simulator
starts it."""

from __future__ import annotations

import re
from dataclasses import dataclass
from functools import partial
from typing import Any

from starlette.concurrency import run_in_threadpool

from adclient.design import DesignSpace
from adclient.designs import Design, Representation
from adclient.schemas import Spawn, TaskConfig
from adclient.xml_data import NOT_DATA
from adservice.db import Database
from adservice.errors import InvalidError
from adservice.expansions import Checks, Expansion, ExpansionPool, expand_each
from adservice.repository import studies as study_repo
from adservice.repository import trials as trial_repo
from adservice.repository import urdfs as urdf_repo
from adservice.services.urdfs import task_links


@dataclass(frozen=True)
class _Found:
    """A trial's robot as stored: a design (with its URDF's name), a template trial's
    stored expansion, or, for one with none, the template and the params to expand."""

    trial_id: int
    task: dict[str, Any] | None
    design: Design | None = None
    robot_name: str = "robot"
    expansion: Expansion | None = None
    template: tuple[str, dict[str, Any]] | None = None


async def trial_urdf(db: Database, expansions: ExpansionPool, *, trial_id: int) -> str:
    """A design study's trial's URDF, written from its decoded design; a template
    study's, as stored when its params were fixed. A template trial stored before
    URDFs were is expanded once, in the expansion pool (BusyError when it is full), and
    stored; one whose params do not expand is an InvalidError with the template's
    message, stored as well. A stored URDF that is not XML as data (a DTD, entity or
    processing instruction, stored by an older server) is an InvalidError: it is not
    served. Nothing here runs on the event loop but the awaiting."""
    found = await run_in_threadpool(_find, db, trial_id)
    if found.design is not None:
        from adclient.urdf import design_to_urdf

        design = found.design
        return await run_in_threadpool(design_to_urdf, design, robot_name=found.robot_name)
    urdf = await _template_urdf(db, expansions, found)
    problem = await run_in_threadpool(_not_data, urdf)
    if problem is not None:
        raise InvalidError(f"trial {trial_id}'s stored URDF is not served: {problem}")
    return urdf


async def trial_spawn(db: Database, expansions: ExpansionPool, *, trial_id: int) -> Spawn:
    """Where adworker's simulator starts the trial's robot before every episode
    (``adclient.spawn``), its study's task saying whether the base is fixed
    (``TaskSpec.fixed_base``). InvalidError for a box study's trial, for a study with
    no task or an external one (no adworker places its robot), and for a stored URDF
    over ``AD_MAX_URDF_BYTES`` or that builds no robot. The URDF is read in a thread,
    as data (no DTD or entity is expanded), never on the event loop."""
    from adclient.spawn import robot_spawn
    from adclient.urdf_model import URDFModelError

    found = await run_in_threadpool(_find, db, trial_id)
    fixed_base = _fixed_base(found)
    if found.design is not None:
        return await run_in_threadpool(
            partial(robot_spawn, found.design, None, fixed_base=fixed_base)
        )
    urdf = await _template_urdf(db, expansions, found)
    limit = expansions.limits.per_urdf()
    size = len(urdf.encode())
    if size > limit.bytes:
        raise InvalidError(
            f"trial {trial_id}'s URDF is {size:,} bytes, over {limit.text()}: no robot is "
            "read from it"
        )
    try:
        return await run_in_threadpool(partial(robot_spawn, None, urdf, fixed_base=fixed_base))
    except URDFModelError as error:
        raise InvalidError(f"trial {trial_id}'s URDF builds no robot: {error}") from None


_NOT_DATA = re.compile(r"<!(?:DOCTYPE|ENTITY)|<\?")


def _not_data(urdf: str) -> str | None:
    """Where a stored URDF holds a DTD, an entity declaration or a processing
    instruction (after its XML declaration), found by one scan: none is ever parsed."""
    body = urdf
    if body.startswith("<?xml"):
        body = body[body.find("?>") + 2 :]
    found = _NOT_DATA.search(body)
    if found is None:
        return None
    line = urdf.count("\n", 0, len(urdf) - len(body) + found.start()) + 1
    construct = "a processing instruction" if found.group() == "<?" else f"{found.group()}"
    return f"line {line}: {construct} {NOT_DATA}"


def _fixed_base(found: _Found) -> bool:
    from adclient.plugins import PluginError, catalogue

    task = None if found.task is None else TaskConfig.model_validate(found.task)
    if task is None or task.external:
        kind = "no task" if task is None else f"an external task ({task.name})"
        raise InvalidError(
            f"trial {found.trial_id}'s study has {kind}: no adworker simulator places its "
            "robot, so it has no spawn pose"
        )
    try:
        return catalogue().task(task.name).fixed_base
    except PluginError as error:
        raise InvalidError(f"trial {found.trial_id}'s task: {error}") from None


async def _template_urdf(db: Database, expansions: ExpansionPool, found: _Found) -> str:
    if found.expansion is not None:
        return found.expansion.text()
    assert found.template is not None
    template, params = found.template
    task = None if found.task is None else TaskConfig.model_validate(found.task)
    checks = Checks(links=task_links(task), per_urdf=expansions.limits.per_urdf())
    (expansion,) = await expansions.run(partial(expand_each, template, [params], checks))

    def store() -> None:
        with db.write() as session:
            urdf_repo.store_urdfs(session, expansions={found.trial_id: expansion})

    await db.run(store)
    return expansion.text()


def _find(db: Database, trial_id: int) -> _Found:
    from adclient.decode import decode

    with db.read() as session:
        trial = trial_repo.get_trial(session, trial_id=trial_id)
        study = study_repo.get_study(session, study_id=trial.study_id)
        if study.space.get("type") == "template":
            stored = urdf_repo.stored_urdfs(session, trial_ids=[trial_id]).get(trial_id)
            if stored is not None:
                return _Found(trial_id, study.task, expansion=stored)
            return _Found(trial_id, study.task, template=(study.space["template"], trial.params))
    if study.representation is None:
        raise InvalidError(f"trial {trial_id} belongs to a box study: it has no robot design")
    space = DesignSpace.model_validate(study.space)
    design = decode(space, Representation.model_validate(study.representation), trial.vector)
    return _Found(
        trial_id, study.task, design=design, robot_name=f"study{study.id}_trial{trial.number}"
    )
