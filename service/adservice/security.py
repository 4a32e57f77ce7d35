"""Browser-facing defences: security headers on every answer, and no state change that
another web page could make on a visitor's behalf.

A page on another origin can send a "simple" cross-site request (a form post, a
``no-cors`` fetch) without asking the server first; such a request can carry neither a
JSON content type nor a custom header. So every state-changing API request must carry
one of them: ``Content-Type: application/json``, the SDK's ``X-Activedesign-Client`` or
the dashboard's ``X-CSRF-Token``. This matters most with auth off (loopback), where no
token stands in the way.
"""

from __future__ import annotations

from fastapi.responses import JSONResponse
from starlette.datastructures import MutableHeaders
from starlette.types import ASGIApp, Message, Receive, Scope, Send

CONTENT_SECURITY_POLICY = (
    "default-src 'self'; script-src 'self'; style-src 'self' 'unsafe-inline'; "
    "img-src 'self' data:; connect-src 'self'; object-src 'none'; base-uri 'none'; "
    "form-action 'self'; frame-ancestors 'none'"
)
"""No inline or foreign script; inline style attributes only (the dashboard's bars)."""
SECURITY_HEADERS = {
    "X-Content-Type-Options": "nosniff",
    "X-Frame-Options": "DENY",
    "Referrer-Policy": "no-referrer",
    "Cross-Origin-Opener-Policy": "same-origin",
}
CHANGE_HEADERS = (b"x-activedesign-client", b"x-csrf-token")
SAFE_METHODS = frozenset({"GET", "HEAD", "OPTIONS"})


class SecurityHeaders:
    """Pure ASGI middleware: the headers above on every response; the CSP unless the
    response set a stricter one of its own (artifacts are sandboxed)."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return

        async def send_with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                headers = MutableHeaders(scope=message)
                for name, value in SECURITY_HEADERS.items():
                    headers.setdefault(name, value)
                headers.setdefault("Content-Security-Policy", CONTENT_SECURITY_POLICY)
            await send(message)

        await self.app(scope, receive, send_with_headers)


def is_json(content_type: bytes) -> bool:
    media = content_type.split(b";")[0].strip().lower()
    return media == b"application/json" or media.endswith(b"+json")


class RefuseSimpleCrossSiteChanges:
    """Pure ASGI middleware: a state-changing /api request that another origin's page
    could send unasked (no JSON body, no custom header) is answered 415."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if (
            scope["type"] == "http"
            and scope["method"] not in SAFE_METHODS
            and scope["path"].startswith("/api/")
        ):
            headers = dict(scope["headers"])
            if not is_json(headers.get(b"content-type", b"")) and not any(
                name in headers for name in CHANGE_HEADERS
            ):
                response = JSONResponse(
                    {
                        "error": "unsupported_media_type",
                        "detail": "a request that changes something must send a JSON body "
                        "(Content-Type: application/json) or the X-Activedesign-Client "
                        "header: other web pages can send neither without the server's leave",
                    },
                    status_code=415,
                )
                await response(scope, receive, send)
                return
        await self.app(scope, receive, send)
