"""The robot behind a trial: its decoded design and URDF."""

from __future__ import annotations

from functools import partial
from typing import Any

from starlette.concurrency import run_in_threadpool

from adclient.design import DesignSpace
from adclient.designs import Representation
from adservice.db import Database
from adservice.errors import InvalidError
from adservice.expansions import Expansion, ExpansionPool, expand_each
from adservice.repository import studies as study_repo
from adservice.repository import trials as trial_repo
from adservice.repository import urdfs as urdf_repo


async def trial_urdf(db: Database, expansions: ExpansionPool, *, trial_id: int) -> str:
    """A design study's trial's URDF, written from its decoded design; a template
    study's, as stored when its params were fixed. A template trial stored before
    URDFs were is expanded once, in the expansion pool (BusyError when it is full), and
    stored; one whose params do not expand is an InvalidError with the template's
    message, stored as well."""
    found = await run_in_threadpool(_stored_or_written, db, trial_id)
    if isinstance(found, str):
        return found
    if isinstance(found, Expansion):
        return found.text()
    template, params = found
    (expansion,) = await expansions.run(partial(expand_each, template, [params]))

    def store() -> None:
        with db.write() as session:
            urdf_repo.store_urdfs(session, expansions={trial_id: expansion})

    await db.run(store)
    return expansion.text()


def _stored_or_written(db: Database, trial_id: int) -> str | Expansion | tuple[str, dict[str, Any]]:
    """A design's URDF; a template trial's stored expansion; or, for a template trial
    with none, the template and the params to expand it at."""
    from adclient.decode import decode
    from adclient.urdf import design_to_urdf

    with db.read() as session:
        trial = trial_repo.get_trial(session, trial_id=trial_id)
        study = study_repo.get_study(session, study_id=trial.study_id)
        if study.space.get("type") == "template":
            stored = urdf_repo.stored_urdfs(session, trial_ids=[trial_id]).get(trial_id)
            return stored or (study.space["template"], trial.params)
    if study.representation is None:
        raise InvalidError(f"trial {trial_id} belongs to a box study: it has no robot design")
    space = DesignSpace.model_validate(study.space)
    design = decode(space, Representation.model_validate(study.representation), trial.vector)
    return design_to_urdf(design, robot_name=f"study{study.id}_trial{trial.number}")
