"""Browser-facing defences: security headers on every answer, and no state change that
another web page could make on a visitor's behalf.

A page on another origin can send a "simple" cross-site request (a form post, a
``no-cors`` fetch) without asking the server first: only a POST (or GET/HEAD) with no
content type or a CORS-simple one (a form's, ``text/plain``) and no custom header. So
such a POST to the API is refused unless it carries one of the SDK's
``X-Activedesign-Client`` or the dashboard's ``X-CSRF-Token``; a JSON body, or any
other content type, is preflighted by a browser, which this server never answers with
CORS leave. DELETE, PUT and PATCH are always preflighted, so they pass to
authentication as any REST client expects (``curl -X DELETE``). This matters most with
auth off (loopback), where no token stands in the way.
"""

from __future__ import annotations

from collections.abc import Mapping
from urllib.parse import urlsplit

from fastapi.responses import JSONResponse
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
API_HEADERS = {
    "X-Content-Type-Options": "nosniff",
    "Content-Security-Policy": "default-src 'none'; frame-ancestors 'none'",
}
"""What a JSON answer needs (opened in a browser it runs and embeds nothing); fewer
bytes on the API's hot path than a page's set."""
CHANGE_HEADERS = (b"x-activedesign-client", b"x-csrf-token")
SAFE_METHODS = frozenset({"GET", "HEAD", "OPTIONS"})
SIMPLE_CONTENT_TYPES = frozenset(
    {b"", b"application/x-www-form-urlencoded", b"multipart/form-data", b"text/plain"}
)
"""What a browser sends cross-site without a preflight (the Fetch standard's
CORS-safelisted request header values of ``Content-Type``, or none)."""


def is_simple(content_type: bytes) -> bool:
    return content_type.split(b";")[0].strip().lower() in SIMPLE_CONTENT_TYPES


def host_name(host: bytes) -> str:
    """The name in a ``Host`` header, without its port (IPv6 literals keep brackets)."""
    text = host.decode("latin-1").strip().lower()
    if text.startswith("["):
        return text[: text.find("]") + 1]
    return text.rsplit(":", 1)[0] if text.count(":") == 1 else text


OWN_FETCH_SITES = frozenset({"same-origin", "none"})
"""``Sec-Fetch-Site`` values of the server's own pages (``none``: typed in the address
bar); ``same-site`` is a sibling host's page, ``cross-site`` any other site's."""


def _origin(url: str) -> tuple[str, str, int] | None:
    """Scheme, host name and port of an origin (the scheme's port where none is given);
    None for ``null`` or anything else that is not one."""
    try:
        parts = urlsplit(url.strip().lower())
        port = parts.port or {"http": 80, "https": 443}.get(parts.scheme)
    except ValueError:
        return None
    if parts.hostname is None or port is None:
        return None
    return parts.scheme, parts.hostname, port


def from_own_origin(headers: Mapping[str, str], scheme: str, public_url: str | None) -> bool:
    """Whether a request comes from the server's own pages, where a browser says: its
    ``Sec-Fetch-Site`` is one of :data:`OWN_FETCH_SITES` and its ``Origin`` is the origin
    it was sent to (its scheme and ``Host``) or ``AD_PUBLIC_URL``'s (behind a proxy).
    A request with neither header (no browser, or an old one's same-origin GET) passes."""
    site = headers.get("sec-fetch-site")
    if site is not None and site.strip().lower() not in OWN_FETCH_SITES:
        return False
    origin = headers.get("origin")
    if origin is None:
        return True
    own = {_origin(f"{scheme}://{headers.get('host', '')}")}
    if public_url:
        own.add(_origin(public_url))
    return (sent := _origin(origin)) is not None and sent in own


def _encoded(headers: dict[str, str]) -> list[tuple[bytes, bytes]]:
    return [(name.lower().encode(), value.encode()) for name, value in headers.items()]


class BrowserEdge:
    """Pure ASGI middleware, the outermost: a ``Host`` the server is not served under is
    400 (DNS rebinding); a POST to /api that another origin's page could send unasked (a
    simple content type, no custom header) is 415; every answer, errors included,
    carries the headers above (the CSP unless the answer set a stricter one of its own:
    artifacts are sandboxed). One layer, not three: it runs on every request."""

    def __init__(self, app: ASGIApp, *, allowed_hosts: list[str]) -> None:
        self.app = app
        patterns = [host.lower() for host in allowed_hosts]
        self.any_host = "*" in patterns
        self.hosts = frozenset(p for p in patterns if not p.startswith("*"))
        self.suffixes = tuple(p[1:] for p in patterns if p.startswith("*."))
        page = {**SECURITY_HEADERS, "Content-Security-Policy": CONTENT_SECURITY_POLICY}
        self.page_headers = _encoded(page)
        self.api_headers = _encoded(API_HEADERS)

    def _host_allowed(self, host: bytes | None) -> bool:
        if self.any_host:
            return True
        if not host:
            return False
        name = host_name(host)
        return name in self.hosts or name.endswith(self.suffixes)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        headers = dict(scope["headers"])
        added = self.api_headers if scope["path"].startswith("/api/") else self.page_headers

        async def send_with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                present = {name.lower() for name, _ in message.get("headers", ())}
                message["headers"] = [
                    *message.get("headers", ()),
                    *(pair for pair in added if pair[0] not in present),
                ]
            await send(message)

        if not self._host_allowed(headers.get(b"host")):
            refused = JSONResponse(
                {"error": "invalid_host", "detail": "this server is not served under that Host"},
                status_code=400,
            )
            await refused(scope, receive, send_with_headers)
            return
        if (
            scope["method"] == "POST"
            and scope["path"].startswith("/api/")
            and is_simple(headers.get(b"content-type", b""))
            and not any(name in headers for name in CHANGE_HEADERS)
        ):
            refused = JSONResponse(
                {
                    "error": "unsupported_media_type",
                    "detail": "a POST must send a JSON body (Content-Type: "
                    "application/json) or the X-Activedesign-Client header: other web "
                    "pages can send neither without the server's leave",
                },
                status_code=415,
            )
            await refused(scope, receive, send_with_headers)
            return
        await self.app(scope, receive, send_with_headers)
