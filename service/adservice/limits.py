"""A deadline for request bodies: uvicorn waits forever for a body that stops arriving."""

from __future__ import annotations

import asyncio

from starlette.types import ASGIApp, Message, Receive, Scope, Send

TIMED_OUT_BODY = b'{"error":"timeout","detail":"request body not received in time"}'


class BodyTimedOut(Exception):
    """Raised into the app from ``receive``: its body will not come."""


class BodyTimeout:
    """Pure ASGI middleware: a request's body must be complete within ``timeout`` seconds
    of the app being called (its headers' end). Past it the client gets 408 with
    ``Connection: close``, and the app's ``receive`` raises so the route stops waiting;
    whatever the app sends afterwards is dropped."""

    def __init__(self, app: ASGIApp, *, timeout: float) -> None:
        self.app = app
        self.timeout = timeout

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        deadline = asyncio.get_running_loop().time() + self.timeout
        body_done = False
        response_started = False
        answered = False

        async def timed_receive() -> Message:
            nonlocal body_done, answered
            if body_done:
                return await receive()
            try:
                async with asyncio.timeout_at(deadline):
                    message = await receive()
            except TimeoutError:
                if not response_started:
                    answered = True
                    await send(
                        {
                            "type": "http.response.start",
                            "status": 408,
                            "headers": [
                                (b"content-type", b"application/json"),
                                (b"content-length", str(len(TIMED_OUT_BODY)).encode()),
                                (b"connection", b"close"),
                            ],
                        }
                    )
                    await send({"type": "http.response.body", "body": TIMED_OUT_BODY})
                raise BodyTimedOut from None
            if message["type"] != "http.request" or not message.get("more_body", False):
                body_done = True
            return message

        async def tracked_send(message: Message) -> None:
            nonlocal response_started
            if answered:
                return
            response_started = True
            await send(message)

        try:
            await self.app(scope, timed_receive, tracked_send)
        except BodyTimedOut:
            if not answered:  # the response had begun: uvicorn closes the connection
                raise
