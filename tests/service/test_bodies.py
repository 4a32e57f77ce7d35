"""A body read off the event loop (adservice.api.bodies) is answered as FastAPI answers a
declared body, error for error, through the server's own error handlers; and its model is
validated in a worker thread, never on the event loop's.

No ``from __future__ import annotations`` here: FastAPI reads the declared route's body
model from its annotation, which must be the class, not the name of a local."""

import threading
from typing import Any

import pytest
from fastapi import FastAPI, Request
from fastapi.testclient import TestClient
from pydantic import BaseModel, field_validator

from adclient.schemas import StudyCreate
from adservice.api.bodies import read_body
from adservice.app import install_error_handlers

VALIDATED_IN: list[str] = []


class Probe(BaseModel):
    """A model that records the thread that validates it."""

    name: str
    count: int = 0

    @field_validator("name")
    @classmethod
    def _record(cls, value: str) -> str:
        VALIDATED_IN.append(threading.current_thread().name)
        return value


def app_of(model: type[BaseModel]) -> FastAPI:
    app = FastAPI()
    install_error_handlers(app)

    @app.post("/declared")
    async def declared(body: model) -> dict[str, Any]:  # type: ignore[valid-type]
        return body.model_dump(mode="json")  # type: ignore[attr-defined]

    @app.post("/read")
    async def read(request: Request) -> dict[str, Any]:
        return (await read_body(request, model)).model_dump(mode="json")

    return app


BODIES: list[tuple[bytes, dict[str, str]]] = [
    (b'{"name": "a", "count": 3}', {"content-type": "application/json"}),
    (b'{"name": "a", "count": 3.5}', {"content-type": "application/json"}),
    (b'{"count": 3}', {"content-type": "application/json"}),
    (b"null", {"content-type": "application/json"}),
    (b"[1, 2]", {"content-type": "application/json"}),
    (b'{"name": "a",', {"content-type": "application/json"}),
    (b'{"name": "\xff"}', {"content-type": "application/json"}),
    (b"[" * 100_000 + b"]" * 100_000, {"content-type": "application/json"}),
    (b'{"name": "a"}', {"content-type": "text/plain"}),
    (b'{"name": "a"}', {"content-type": "application/vnd.api+json; charset=utf-8"}),
    (b'{"name": "a"}', {}),
    (b"", {"content-type": "application/json"}),
]


@pytest.mark.parametrize(("raw", "headers"), BODIES, ids=range(len(BODIES)))
def test_a_body_read_off_the_loop_is_answered_as_a_declared_one(
    raw: bytes, headers: dict[str, str]
) -> None:
    with TestClient(app_of(Probe)) as client:
        declared = client.post("/declared", content=raw, headers=headers)
        read = client.post("/read", content=raw, headers=headers)
    assert (read.status_code, read.json()) == (declared.status_code, declared.json())


def test_a_study_creations_errors_are_a_declared_bodys() -> None:
    body = {
        "name": "s",
        "space": {"type": "box", "params": [{"name": "x", "low": 1, "high": 0}]},
        "proposer": {"name": "random", "seed": "1"},
        "max_trials": True,
    }
    with TestClient(app_of(StudyCreate)) as client:
        declared = client.post("/declared", json=body)
        read = client.post("/read", json=body)
    assert read.status_code == declared.status_code == 422
    assert read.json() == declared.json()


def test_the_model_is_validated_in_a_worker_thread() -> None:
    VALIDATED_IN.clear()
    with TestClient(app_of(Probe)) as client:
        assert client.post("/read", json={"name": "a"}).status_code == 200
        assert client.post("/declared", json={"name": "a"}).status_code == 200
    read, declared = VALIDATED_IN
    assert read != declared, VALIDATED_IN  # the event loop's thread validates a declared body
    assert read.startswith(("AnyIO worker", "ThreadPoolExecutor")), VALIDATED_IN


def test_a_study_creation_is_served_by_the_route_that_reads_its_body_off_the_loop() -> None:
    """The first route that matches ``POST /api/v1/studies`` (the one served) declares no
    body, so FastAPI validates none on the event loop; the documented twin after it
    declares ``StudyCreate`` for the OpenAPI schema."""
    from fastapi.routing import APIRoute, iter_route_contexts

    from adservice.app import create_app

    app = create_app()
    matching = [
        context.original_route
        for context in iter_route_contexts(app.router.routes)
        if isinstance(context.original_route, APIRoute)
        and context.path == "/api/v1/studies"
        and "POST" in (context.methods or ())
    ]
    served, documented = matching
    assert not served.dependant.body_params and not served.include_in_schema
    assert [param.name for param in documented.dependant.body_params] == ["body"]
    schema = app.openapi()["paths"]["/api/v1/studies"]["post"]
    assert schema["requestBody"]["content"]["application/json"]["schema"] == {
        "$ref": "#/components/schemas/StudyCreate"
    }
