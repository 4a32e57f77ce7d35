"""Limits on request bodies: a size (413) and a deadline (408).

uvicorn reads whatever body a client sends, for as long as it takes; these limits are
checked as the body arrives, before a route has read it.
"""

from __future__ import annotations

import asyncio

from starlette.responses import JSONResponse
from starlette.routing import compile_path
from starlette.types import ASGIApp, Message, Receive, Scope, Send

ARTIFACT_UPLOAD_PATH = "/api/v1/trials/{trial_id}/artifacts/{name}"
"""The one route whose body may be an artifact (``PUT``, api/routes/artifacts.py): only
its body takes the artifact limit."""
_ARTIFACT_UPLOAD = compile_path(ARTIFACT_UPLOAD_PATH)[0]


def is_artifact_upload(scope: Scope) -> bool:
    """Whether the request is an artifact upload, matched as its route matches it."""
    return scope["method"] == "PUT" and _ARTIFACT_UPLOAD.match(scope["path"]) is not None


class BodyRefused(Exception):
    """Raised into the app from ``receive`` once its body is refused (the client has had
    its 413 or 408 by then, unless the app had begun answering)."""


class BodyLimits:
    """Pure ASGI middleware: a body must fit the limit (``artifact_limit`` for the
    artifact upload route alone, :func:`is_artifact_upload`) and be complete within
    ``timeout`` seconds of its headers' end.

    A declared ``Content-Length`` over the limit is answered at once. Otherwise the body
    is counted and timed as it arrives; past either limit the middleware answers itself,
    with ``Connection: close`` (the rest is never read), makes the app's ``receive``
    raise so the route stops waiting, and drops whatever the app sends after: FastAPI
    turns any error while it reads a body into a 400."""

    def __init__(self, app: ASGIApp, *, limit: int, artifact_limit: int, timeout: float) -> None:
        self.app = app
        self.limit = limit
        self.artifact_limit = artifact_limit
        self.timeout = timeout

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        upload = is_artifact_upload(scope)
        allowed = self.artifact_limit if upload else self.limit
        setting = "AD_MAX_ARTIFACT_BYTES" if upload else "AD_MAX_BODY_BYTES"
        declared = dict(scope["headers"]).get(b"content-length")
        if declared is not None and not declared.isdigit():
            invalid = {"error": "invalid", "detail": "Content-Length must be a number"}
            await JSONResponse(invalid, status_code=400)(scope, receive, send)
            return
        if declared is not None and int(declared) > allowed:
            await _too_large(allowed, setting)(scope, receive, send)
            return
        deadline = asyncio.get_running_loop().time() + self.timeout
        received = 0
        body_done = started = answered = False

        async def refuse(response: JSONResponse) -> None:
            nonlocal answered
            if not started and not answered:
                answered = True
                await response(scope, receive, send)
            raise BodyRefused

        async def limited_receive() -> Message:
            nonlocal received, body_done
            if body_done:
                return await receive()
            try:
                async with asyncio.timeout_at(deadline):
                    message = await receive()
            except TimeoutError:
                await refuse(_timed_out())
            if message["type"] != "http.request":
                body_done = True
                return message
            received += len(message.get("body", b""))
            if received > allowed:
                await refuse(_too_large(allowed, setting))
            body_done = not message.get("more_body", False)
            return message

        async def tracked_send(message: Message) -> None:
            nonlocal started
            if answered:
                return
            started = True
            await send(message)

        try:
            await self.app(scope, limited_receive, tracked_send)
        except BodyRefused:
            if not answered:  # the app had begun its answer: uvicorn closes the connection
                raise


def _too_large(allowed: int, setting: str) -> JSONResponse:
    detail = f"body exceeds the limit of {allowed} bytes ({setting})"
    return JSONResponse(
        {"error": "too_large", "detail": detail},
        status_code=413,
        headers={"Connection": "close"},
    )


def _timed_out() -> JSONResponse:
    return JSONResponse(
        {"error": "timeout", "detail": "request body not received in time"},
        status_code=408,
        headers={"Connection": "close"},
    )
