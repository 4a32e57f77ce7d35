"""A request body decoded and validated off the event loop.

FastAPI decodes and validates a declared body on the event loop, before the route runs.
For most bodies that is a fraction of a millisecond; a study creation's design space is
up to a megabyte of structures whose checks (every tree, its specs, its joints) take
23 ms for the issue-58 space of 200 random 32-link trees and about 0.1 s for a
megabyte, during which no other request of any user is served. A route that takes such
a body reads it with :func:`read_body` instead, which does the same in a worker thread
and answers errors exactly as FastAPI does for a declared body (the same locations and
messages, through the same handlers). Its OpenAPI operation is documented by a twin
route that declares the model and is never served (the route served is registered
first).
"""

from __future__ import annotations

import email.message
import json
from typing import Any, TypeVar

from fastapi import HTTPException, Request
from fastapi.dependencies.utils import get_missing_field_error
from fastapi.exceptions import RequestValidationError
from pydantic import BaseModel, ValidationError
from starlette.concurrency import run_in_threadpool

M = TypeVar("M", bound=BaseModel)
_ABSENT = object()


async def read_body(request: Request, model: type[M]) -> M:
    """The request's JSON body as ``model``, decoded and validated in a worker thread;
    RequestValidationError (422) or HTTPException (400, for a body the JSON parser cannot
    read) as FastAPI raises them for a declared body parameter."""
    raw = await request.body()
    return await run_in_threadpool(_parse, model, raw, request.headers.get("content-type"))


def _parse(model: type[M], raw: bytes, content_type: str | None) -> M:
    body: Any = _ABSENT
    if raw:
        if _is_json(content_type):
            try:
                body = json.loads(raw)
            except json.JSONDecodeError as error:
                raise RequestValidationError(
                    [
                        {
                            "type": "json_invalid",
                            "loc": ("body", error.pos),
                            "msg": "JSON decode error",
                            "input": {},
                            "ctx": {"error": error.msg},
                        }
                    ],
                    body=error.doc,
                ) from error
            except Exception as error:  # nesting past the parser, not UTF-8, huge integers
                raise HTTPException(
                    status_code=400, detail="There was an error parsing the body"
                ) from error
        else:
            body = raw
    if body is _ABSENT:
        raise RequestValidationError([get_missing_field_error(loc=("body",))])
    try:
        return model.model_validate(body, from_attributes=True)
    except ValidationError as error:
        raise RequestValidationError(
            [
                {**item, "loc": ("body", *item.get("loc", ()))}
                for item in error.errors(include_url=False)
            ],
            body=body,
        ) from None


def _is_json(content_type: str | None) -> bool:
    """Whether FastAPI reads a body of this content type as JSON (a strict content type:
    a body without one is not)."""
    if not content_type:
        return False
    message = email.message.Message()
    message["content-type"] = content_type
    subtype = message.get_content_subtype()
    return message.get_content_maintype() == "application" and (
        subtype == "json" or subtype.endswith("+json")
    )
