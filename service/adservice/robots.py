"""The robot behind a trial: its decoded design and URDF."""

from __future__ import annotations

from typing import Any

from sqlalchemy.orm import Session

from adclient.design import DesignSpace
from adclient.designs import Representation
from adservice.errors import InvalidError
from adservice.repository import studies as study_repo
from adservice.repository import trials as trial_repo


def trial_urdf(session: Session, *, trial_id: int) -> str:
    from adclient.decode import decode
    from adclient.urdf import design_to_urdf

    trial = trial_repo.get_trial(session, trial_id=trial_id)
    study = study_repo.get_study(session, study_id=trial.study_id)
    if study.space.get("type") == "template":
        return _template_urdf(study.space["template"], trial.params)
    if study.representation is None:
        raise InvalidError(f"trial {trial_id} belongs to a box study: it has no robot design")
    space = DesignSpace.model_validate(study.space)
    design = decode(space, Representation.model_validate(study.representation), trial.vector)
    return design_to_urdf(design, robot_name=f"study{study.id}_trial{trial.number}")


def _template_urdf(template: str, params: dict[str, Any]) -> str:
    """The user's template expanded at the trial's params (in a child process)."""
    from adclient.templates import TemplateError, expand_isolated

    try:
        (urdf,) = expand_isolated(template, [params])
    except TemplateError as error:  # the template expanded when the study was created
        raise InvalidError(f"the trial's template does not expand: {error}") from None
    return urdf
