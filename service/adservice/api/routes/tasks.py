"""The installed tasks: what a study may name, each with its options' JSON schema and
how it holds its robot and the engines it runs on."""

from __future__ import annotations

import functools

from fastapi import APIRouter

from adclient.plugins import catalogue
from adclient.schemas import TaskInfo
from adservice.api.deps import ReaderDep

router = APIRouter(prefix="/api/v1/tasks", tags=["catalogue"])


@functools.cache
def _tasks() -> list[TaskInfo]:
    return [
        TaskInfo(
            name=name,
            description=spec.description,
            options_schema=spec.options.model_json_schema(),
            fixed_base=spec.fixed_base,
            templates=spec.templates,
            simulators=list(spec.simulators),
        )
        for name, spec in sorted(catalogue().tasks.items())
    ]


@router.get("", response_model=list[TaskInfo])
async def list_tasks(_caller: ReaderDep) -> list[TaskInfo]:
    return _tasks()
