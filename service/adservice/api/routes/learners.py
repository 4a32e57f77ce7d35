"""The installed learners: what a study's ``task.learner`` may be, with the JSON schema
of the ``learner_kwargs`` each accepts."""

from __future__ import annotations

import functools

from fastapi import APIRouter

from adclient.plugins import SIMULATORS, catalogue
from adclient.schemas import LearnerInfo
from adservice.api.deps import ReaderDep

router = APIRouter(prefix="/api/v1/learners", tags=["catalogue"])


@functools.cache
def _learners() -> list[LearnerInfo]:
    return [
        LearnerInfo(
            name=name,
            description=spec.description,
            options_schema=spec.options.model_json_schema() if spec.options else None,
            simulators=list(spec.simulators or SIMULATORS),
        )
        for name, spec in sorted(catalogue().learners.items())
    ]


@router.get("", response_model=list[LearnerInfo])
async def list_learners(_caller: ReaderDep) -> list[LearnerInfo]:
    return _learners()
