"""Who is calling, and what their role lets them do: reader < worker < user < admin.

- reader: every GET, so the dashboard and read-only clients;
- worker: also lease jobs, and heartbeat, release, upload artifacts for and tell the
  trials its own token leased (a lease belongs to the token that took it);
- user: also create studies, and ask, tell, stop the studies it created;
- admin: everything, on every study; fails or releases any trial.

A caller proves who it is with ``Authorization: Bearer <token>`` or, in a browser, with
the dashboard's session cookie (see ``adservice.api.routes.session``); a state change made
with the cookie must also carry the session's CSRF token in ``X-CSRF-Token``. Only
SHA-256 digests of tokens and session ids are stored. Auth is off only when the server
binds to loopback and nobody turned it on (see ``adservice.cli``); then every caller is
an admin, and a worker is known by the ``worker_id`` it sends.

Authentication runs as middleware, before a route parses its body: a caller without a
valid token learns 401, and a caller whose role a change's route does not admit 403,
before its body is read (never anything about the body it sent).
"""

from __future__ import annotations

import hashlib
import hmac
import re
import secrets
import threading
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from http.cookies import SimpleCookie

from fastapi import Request
from fastapi.dependencies.models import Dependant
from fastapi.responses import JSONResponse
from fastapi.routing import APIRoute, iter_route_contexts
from starlette.concurrency import run_in_threadpool
from starlette.routing import BaseRoute, compile_path
from starlette.types import ASGIApp, Receive, Scope, Send

from adservice.db import Database
from adservice.errors import DomainError, ForbiddenError, UnauthorizedError
from adservice.principals import OPEN_ADMIN, RANK, Principal, Role
from adservice.repository import tokens as token_repo
from adservice.security import SAFE_METHODS

CACHE_SECONDS = 5.0
"""How long a looked-up token or session is trusted before the database is asked again
(a revoked token, or a signed-out session, stops working within this time)."""

SESSION_COOKIE = "ad_session"
CSRF_HEADER = "x-csrf-token"
PUBLIC_API_PATHS = frozenset({"/api/v1/session"})
"""API paths that answer without a principal (signing in, asking whether one is needed)."""
SCRAPED_PATHS = frozenset({"/metrics"})
"""Paths outside /api that need a principal too: Prometheus scrapes with a reader token."""


def new_token() -> str:
    return "adt_" + secrets.token_urlsafe(32)


def new_session_id() -> str:
    return secrets.token_urlsafe(32)


def token_digest(secret: str) -> str:
    """The SHA-256 of a token or session id: 256 random bits need no slow hash."""
    return hashlib.sha256(secret.encode()).hexdigest()


class PrincipalCache:
    """Digest -> principal (or None for unknown), for a few seconds."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._entries: dict[str, tuple[float, Principal | None]] = {}

    def get(self, key: str) -> tuple[bool, Principal | None]:
        with self._lock:
            entry = self._entries.get(key)
        if entry is None or entry[0] < time.monotonic():
            return False, None
        return True, entry[1]

    def put(self, key: str, principal: Principal | None) -> None:
        with self._lock:
            if len(self._entries) > 10_000:
                self._entries.clear()
            self._entries[key] = (time.monotonic() + CACHE_SECONDS, principal)

    def forget(self, key: str) -> None:
        with self._lock:
            self._entries.pop(key, None)


def _bearer(headers: dict[bytes, bytes]) -> str | None:
    header = headers.get(b"authorization")
    if header is None:
        return None
    scheme, _, token = header.decode("latin-1").partition(" ")
    if scheme.lower() != "bearer" or not token.strip():
        raise UnauthorizedError("a bearer token is required (Authorization: Bearer <token>)")
    return token.strip()


def session_id_of(headers: dict[bytes, bytes]) -> str | None:
    raw = headers.get(b"cookie")
    if raw is None:
        return None
    cookie: SimpleCookie = SimpleCookie()
    try:
        cookie.load(raw.decode("latin-1"))
    except Exception:  # a malformed cookie header is as good as none
        return None
    morsel = cookie.get(SESSION_COOKIE)
    return morsel.value if morsel is not None and morsel.value else None


def _look_up_token(db: Database, digest: str) -> Principal | None:
    with db.read() as session:
        row = token_repo.find_token(session, digest=digest)
        return Principal(role=Role(row.role), token_id=row.id, name=row.name) if row else None


def _look_up_session(db: Database, digest: str) -> Principal | None:
    with db.read() as session:
        found = token_repo.find_session(session, digest=digest)
        if found is None:
            return None
        row, token = found
        return Principal(
            role=Role(token.role), token_id=token.id, name=token.name, csrf_token=row.csrf_token
        )


async def _resolve(
    db: Database,
    cache: PrincipalCache,
    key: str,
    look_up: Callable[[Database, str], Principal | None],
    secret_digest: str,
) -> Principal:
    known, principal = cache.get(key)
    if not known:
        principal = await run_in_threadpool(look_up, db, secret_digest)
        cache.put(key, principal)
    if principal is None:
        raise UnauthorizedError("unknown or revoked token, or an expired sign-in")
    return principal


async def authenticate(scope: Scope) -> Principal:
    """The caller of an API request: from its bearer token, else its session cookie."""
    app = scope["app"]
    if not app.state.settings.auth:
        return OPEN_ADMIN
    headers = dict(scope["headers"])
    db: Database = app.state.db
    cache: PrincipalCache = app.state.principals
    token = _bearer(headers)
    if token is not None:
        found = token_digest(token)
        return await _resolve(db, cache, "t:" + found, _look_up_token, found)
    session_id = session_id_of(headers)
    if session_id is None:
        raise UnauthorizedError(
            "a bearer token is required (Authorization: Bearer <token>), or sign in"
        )
    session_digest = token_digest(session_id)
    principal = await _resolve(db, cache, "s:" + session_digest, _look_up_session, session_digest)
    if scope["method"] not in SAFE_METHODS:
        sent = headers.get(CSRF_HEADER.encode(), b"").decode("latin-1")
        assert principal.csrf_token is not None
        if not hmac.compare_digest(sent, principal.csrf_token):
            raise ForbiddenError(
                "a change made with the sign-in cookie needs the session's CSRF token in "
                "X-CSRF-Token (GET /api/v1/session gives it to the dashboard)"
            )
    return principal


def _required_role(dependant: Dependant) -> Role | None:
    """The role a route's dependencies require (:func:`require`), if any."""
    for dependency in dependant.dependencies:
        role = getattr(dependency.call, "required_role", None)
        if isinstance(role, Role):
            return role
        role = _required_role(dependency)
        if role is not None:
            return role
    return None


@dataclass(frozen=True)
class WriteRoute:
    """A route of changes (a method other than GET, HEAD, OPTIONS) and the role it
    requires."""

    methods: frozenset[str]
    path: re.Pattern[str]
    """The route's full path, matched as its router matches it."""
    role: Role

    def serves(self, scope: Scope) -> bool:
        return scope["method"] in self.methods and self.path.match(scope["path"]) is not None


def write_routes(routes: list[BaseRoute]) -> list[WriteRoute]:
    """The app's routes of changes that require a role (:func:`require`), included
    routers' alike: what the middleware matches a change against before its body is
    read."""
    found: list[WriteRoute] = []
    for context in iter_route_contexts(routes):
        route, methods = context.original_route, frozenset(context.methods or ()) - SAFE_METHODS
        role = _required_role(route.dependant) if isinstance(route, APIRoute) else None
        if methods and role is not None and context.path is not None:
            found.append(WriteRoute(methods, compile_path(context.path)[0], role))
    return found


def _refused_role(
    routes: list[WriteRoute], scope: Scope, principal: Principal
) -> ForbiddenError | None:
    """The 403 a change's route would answer the caller's role, found from the path and
    method alone, or None where the role is enough (or no route requires one)."""
    if scope["method"] in SAFE_METHODS:
        return None
    rank = RANK[principal.role]
    for route in routes:
        if RANK[route.role] > rank and route.serves(scope):
            return role_refusal(route.role, principal)
    return None


def role_refusal(role: Role, principal: Principal) -> ForbiddenError:
    return ForbiddenError(
        f"this needs the {role} role or a higher one; the token's role is {principal.role}"
    )


class Authentication:
    """Pure ASGI middleware: every /api request but signing in carries a principal in
    ``scope["state"]["principal"]``, or is answered 401/403 before its route runs: for
    no valid token, and for a change whose route requires a higher role than the
    caller's (both before the body is read: the answer closes the connection, whose rest
    is never read)."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app
        self._write_routes_found: list[WriteRoute] | None = None

    def _write_routes(self, scope: Scope) -> list[WriteRoute]:
        if self._write_routes_found is None:  # the routes are all in place by the first request
            self._write_routes_found = write_routes(scope["app"].router.routes)
        return self._write_routes_found

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        path = scope.get("path", "")
        if (
            scope["type"] != "http"
            or not (path.startswith("/api/") or path in SCRAPED_PATHS)
            or path in PUBLIC_API_PATHS
        ):
            await self.app(scope, receive, send)
            return
        try:
            principal = await authenticate(scope)
            refused = _refused_role(self._write_routes(scope), scope, principal)
            if refused is not None:
                raise refused
            limited = scope["app"].state.rates.refusal(principal, scope)
            if limited is not None:
                await _answer(
                    scope, receive, send, limited, 429, {"Retry-After": str(limited.retry_after)}
                )
                return
        except (UnauthorizedError, ForbiddenError) as error:
            unauthorized = isinstance(error, UnauthorizedError)
            headers = {"WWW-Authenticate": "Bearer"} if unauthorized else {}
            await _answer(scope, receive, send, error, 401 if unauthorized else 403, headers)
            return
        scope.setdefault("state", {})["principal"] = principal
        await self.app(scope, receive, send)


async def _answer(
    scope: Scope,
    receive: Receive,
    send: Send,
    error: DomainError,
    status: int,
    headers: dict[str, str],
) -> None:
    """Answer a request refused before its route runs; one that carries a body is closed
    after the answer (its body is never read)."""
    if _has_body(scope):
        headers = {**headers, "Connection": "close"}
    response = JSONResponse(
        {"error": error.code, "detail": error.detail}, status_code=status, headers=headers
    )
    await response(scope, receive, send)


def _has_body(scope: Scope) -> bool:
    headers = dict(scope["headers"])
    return headers.get(b"content-length", b"0") != b"0" or b"transfer-encoding" in headers


def require(role: Role) -> Callable[[Request], Awaitable[Principal]]:
    """A dependency that admits callers holding ``role`` or a higher one."""

    async def dependency(request: Request) -> Principal:
        principal: Principal = request.state.principal
        if RANK[principal.role] < RANK[role]:
            raise role_refusal(role, principal)
        return principal

    dependency.required_role = role  # type: ignore[attr-defined]  # for write_routes
    return dependency
