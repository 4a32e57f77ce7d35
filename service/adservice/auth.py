"""Bearer tokens with roles: reader < worker < admin.

- reader: every GET, so the dashboard and read-only clients;
- worker: also lease, heartbeat, tell (only the trials it holds) and upload artifacts;
- admin: also create, ask and stop studies.

Only a token's SHA-256 is stored. Auth is off only when the server binds to loopback
and nobody turned it on (see ``adservice.cli``); then every caller is an admin.
"""

from __future__ import annotations

import hashlib
import secrets
import threading
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from enum import StrEnum

from fastapi import Request
from starlette.concurrency import run_in_threadpool

from adservice import repository
from adservice.errors import ForbiddenError, UnauthorizedError

CACHE_SECONDS = 5.0
"""How long a looked-up token is trusted before the database is asked again (a revoked
token stops working within this time)."""


class Role(StrEnum):
    reader = "reader"
    worker = "worker"
    admin = "admin"


RANK = {Role.reader: 0, Role.worker: 1, Role.admin: 2}


@dataclass(frozen=True)
class Principal:
    role: Role
    token_id: int | None


LOOPBACK_ADMIN = Principal(role=Role.admin, token_id=None)


def new_token() -> str:
    return "adt_" + secrets.token_urlsafe(32)


def token_digest(token: str) -> str:
    return hashlib.sha256(token.encode()).hexdigest()


class TokenCache:
    """Token digest -> principal (or None for unknown), for a few seconds."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._entries: dict[str, tuple[float, Principal | None]] = {}

    def get(self, digest: str) -> tuple[bool, Principal | None]:
        with self._lock:
            entry = self._entries.get(digest)
        if entry is None or entry[0] < time.monotonic():
            return False, None
        return True, entry[1]

    def put(self, digest: str, principal: Principal | None) -> None:
        with self._lock:
            if len(self._entries) > 10_000:
                self._entries.clear()
            self._entries[digest] = (time.monotonic() + CACHE_SECONDS, principal)


def _token_digest(request: Request) -> str:
    header = request.headers.get("authorization", "")
    scheme, _, token = header.partition(" ")
    if scheme.lower() != "bearer" or not token:
        raise UnauthorizedError("a bearer token is required (Authorization: Bearer <token>)")
    return token_digest(token.strip())


def _admit(principal: Principal | None) -> Principal:
    if principal is None:
        raise UnauthorizedError("unknown or revoked token")
    return principal


def authenticate_cached(request: Request) -> Principal | None:
    """The caller when that needs no database read (auth off, or the token cached);
    None when it does."""
    state = request.app.state
    if not state.settings.auth:
        return LOOPBACK_ADMIN
    cache: TokenCache = state.tokens
    known, principal = cache.get(_token_digest(request))
    return _admit(principal) if known else None


def authenticate(request: Request) -> Principal:
    principal = authenticate_cached(request)
    if principal is not None:
        return principal
    digest = _token_digest(request)
    state = request.app.state
    with state.db.read() as session:
        row = repository.find_token(session, digest=digest)
        found = Principal(role=Role(row.role), token_id=row.id) if row else None
    state.tokens.put(digest, found)
    return _admit(found)


def require(role: Role) -> Callable[[Request], Awaitable[Principal]]:
    """A dependency that admits callers holding ``role`` or a higher one (async: only a
    token missing from the cache costs a database read, in the thread pool)."""

    async def dependency(request: Request) -> Principal:
        principal = authenticate_cached(request)
        if principal is None:
            principal = await run_in_threadpool(authenticate, request)
        if RANK[principal.role] < RANK[role]:
            raise ForbiddenError(
                f"this needs the {role} role; the token's role is {principal.role}"
            )
        return principal

    return dependency
