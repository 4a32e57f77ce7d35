"""Per-token request rates: how much of the server one user's token may take.

Every request a token sends costs the server's one event loop some CPU before anything
can refuse it: reading and validating its body, its authentication, its answer. A
budget on each request's size bounds one request; these bound how many a token sends.
A ``user`` or ``reader`` token (or a dashboard session made with one) may send at most
``AD_TOKEN_REQUESTS_PER_SECOND`` requests a second, in bursts of up to
``AD_TOKEN_REQUEST_BURST``, and create at most ``AD_TOKEN_CREATIONS_PER_MINUTE`` studies
a minute, in bursts of up to ``AD_TOKEN_CREATION_BURST`` (a design study's body alone is
up to a megabyte of trees to check). Past either, the request is answered 429 with
``Retry-After`` before its body is read, naming the budget and its setting; the SDK
waits that long and sends it again. Worker and admin tokens are not limited (a lab's
shared workers lease under one token; an admin is the operator), nor is any caller with
auth off (every caller is the one admin then).

Each limit is a token bucket per API token: it holds up to the burst and refills at the
rate; a request takes one. The buckets live in the server's memory, one pair per token
that sent a request (tokens are made by an admin, so their count is the admin's), and
start full when the server does.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

from starlette.types import Scope

from adservice.errors import RateLimitedError
from adservice.principals import Principal, Role

LIMITED_ROLES = frozenset({Role.user, Role.reader})
CREATION_PATH = "/api/v1/studies"


@dataclass
class Bucket:
    """A token bucket: ``capacity`` at most, ``rate`` more a second."""

    rate: float
    capacity: float
    level: float = field(init=False)
    at: float = field(default_factory=time.monotonic)

    def __post_init__(self) -> None:
        self.level = self.capacity

    def take(self, now: float) -> float:
        """Take one: 0 when there was one, else the seconds until there is (none taken)."""
        self.level = min(self.capacity, self.level + (now - self.at) * self.rate)
        self.at = now
        if self.level >= 1.0:
            self.level -= 1.0
            return 0.0
        return (1.0 - self.level) / self.rate


@dataclass(frozen=True)
class Limit:
    """One budget: ``rate`` a second in bursts of ``burst``; ``what`` names it in a 429."""

    rate: float
    burst: int
    what: str
    settings: str

    def bucket(self) -> Bucket:
        return Bucket(rate=self.rate, capacity=float(self.burst))


class TokenRates:
    """The request and creation buckets of every limited token (see the module
    docstring); a limit of None is no limit. Used on the event loop alone."""

    def __init__(
        self,
        *,
        requests_per_second: float | None,
        request_burst: int,
        creations_per_minute: float | None,
        creation_burst: int,
    ) -> None:
        self.requests = (
            None
            if requests_per_second is None
            else Limit(
                requests_per_second,
                request_burst,
                f"{requests_per_second:g} requests a second in bursts of {request_burst}",
                "AD_TOKEN_REQUESTS_PER_SECOND, AD_TOKEN_REQUEST_BURST",
            )
        )
        self.creations = (
            None
            if creations_per_minute is None
            else Limit(
                creations_per_minute / 60.0,
                creation_burst,
                f"{creations_per_minute:g} study creations a minute in bursts of {creation_burst}",
                "AD_TOKEN_CREATIONS_PER_MINUTE, AD_TOKEN_CREATION_BURST",
            )
        )
        self._buckets: dict[tuple[str, int], Bucket] = {}

    def refusal(self, principal: Principal, scope: Scope) -> RateLimitedError | None:
        """The 429 this request of ``principal`` gets, or None: it is taken from its
        token's buckets (a creation from both)."""
        if principal.token_id is None or principal.role not in LIMITED_ROLES:
            return None
        now = time.monotonic()
        limits = [self.requests]
        if scope["method"] == "POST" and scope["path"].rstrip("/") == CREATION_PATH:
            limits.append(self.creations)
        for limit in limits:
            if limit is None:
                continue
            key = (limit.settings, principal.token_id)
            bucket = self._buckets.get(key)
            if bucket is None:
                bucket = self._buckets[key] = limit.bucket()
            wait = bucket.take(now)
            if wait > 0:
                whose = f"token {principal.name!r}" if principal.name else "this token"
                return RateLimitedError(
                    f"{whose} may send {limit.what} ({limit.settings}); "
                    f"send it again in {wait:.1f} s",
                    retry_after=max(1, math.ceil(wait)),
                )
        return None
