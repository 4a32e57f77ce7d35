"""The request body size limit: 413 whether the body declares its length or streams it."""

from __future__ import annotations

from starlette.responses import JSONResponse
from starlette.types import ASGIApp, Message, Receive, Scope, Send


class BodyTooLarge(Exception):
    """Raised into the app from ``receive`` once a streamed body passes the limit (the
    client has had its 413 by then)."""


class BodySizeLimit:
    """Pure ASGI middleware: refuse a body larger than the limit before a route reads it.

    A declared ``Content-Length`` over the limit is answered at once. A chunked body is
    counted as it arrives; past the limit the middleware answers 413 itself, with
    ``Connection: close`` (the rest of the body is never read), and drops whatever the
    app sends after: FastAPI turns any error while it reads a body into a 400."""

    def __init__(self, app: ASGIApp, *, limit: int, artifact_limit: int) -> None:
        self.app = app
        self.limit = limit
        self.artifact_limit = artifact_limit

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        allowed = self.artifact_limit if "/artifacts/" in scope["path"] else self.limit
        too_large = JSONResponse(
            {"error": "too_large", "detail": f"body exceeds the limit of {allowed} bytes"},
            status_code=413,
            headers={"Connection": "close"},
        )
        declared = dict(scope["headers"]).get(b"content-length")
        if declared is not None and not declared.isdigit():
            invalid = {"error": "invalid", "detail": "Content-Length must be a number"}
            await JSONResponse(invalid, status_code=400)(scope, receive, send)
            return
        if declared is not None and int(declared) > allowed:
            await too_large(scope, receive, send)
            return
        received = 0
        started = answered = False

        async def counted_receive() -> Message:
            nonlocal received, answered
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > allowed:
                    if not started and not answered:
                        answered = True
                        await too_large(scope, receive, send)
                    raise BodyTooLarge
            return message

        async def tracked_send(message: Message) -> None:
            nonlocal started
            if answered:
                return
            started = True
            await send(message)

        try:
            await self.app(scope, counted_receive, tracked_send)
        except BodyTooLarge:
            if not answered:  # the app had begun its answer: uvicorn closes the connection
                raise
