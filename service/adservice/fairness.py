"""One owner's share of a bounded pool (the creation pool, the expansion pool): places
held and works running, per study owner.

A pool of ``workers`` (children, threads) and places (running or waiting) bounds what
every user together may make the server do; without shares one user's creations or
template expansions could take every place (the next user's request a 503) and every
worker (the next user's work waiting behind them all). So, per owner (a study owner's
token; with auth off there is one user and no shares):

- places: an owner holds at most ``places`` of the pool's places; past them its request
  is a 429 naming the setting, and the other owners still find theirs;
- running: an owner's works run at most ``running`` at a time (one fewer than the pool's
  workers, at least one), the rest waiting for the owner's own turn, not in the pool's
  queue: another owner's work always finds a worker within one work's time.
"""

from __future__ import annotations

import asyncio
import threading
from collections import Counter, deque

from adservice.errors import RateLimitedError

RETRY_AFTER_SECONDS = 5


def running_share(workers: int) -> int:
    """Works one owner may run at once in a pool of ``workers``: all but one, at least one."""
    return max(1, workers - 1)


class OwnerShares:
    """Places and running turns per owner (None: not counted). ``what`` and ``setting``
    name the pool and the places' setting in a refusal. Places are counted under a lock
    (taken from any thread); turns are taken on the event loop and may be given back
    from any thread (:meth:`give_turn_threadsafe`)."""

    def __init__(self, *, places: int, running: int, what: str, setting: str) -> None:
        self.places = places
        self.running = running
        self.what = what
        self.setting = setting
        self._held: Counter[int] = Counter()
        self._busy: Counter[int] = Counter()
        self._waiting: dict[int, deque[asyncio.Future[None]]] = {}
        self._lock = threading.Lock()

    def take_place(self, owner: int | None) -> None:
        """One of the owner's places, or RateLimitedError (429) when it holds them all."""
        if owner is None:
            return
        with self._lock:
            if self._held[owner] >= self.places:
                raise RateLimitedError(
                    f"this study's owner already has {self.places} {self.what} running or "
                    f"waiting ({self.setting}): nothing was done; retry in "
                    f"{RETRY_AFTER_SECONDS} s",
                    retry_after=RETRY_AFTER_SECONDS,
                )
            self._held[owner] += 1

    def give_place(self, owner: int | None) -> None:
        if owner is None:
            return
        with self._lock:
            self._held[owner] -= 1
            if self._held[owner] <= 0:
                del self._held[owner]

    async def take_turn(self, owner: int | None) -> None:
        """Wait until the owner runs fewer than ``running`` works, then count one more;
        a cancelled wait takes none."""
        if owner is None:
            return
        loop = asyncio.get_running_loop()
        while self._busy[owner] >= self.running:
            waiter: asyncio.Future[None] = loop.create_future()
            queue = self._waiting.setdefault(owner, deque())
            queue.append(waiter)
            try:
                await waiter
            finally:
                if waiter in queue:
                    queue.remove(waiter)
                if not queue:
                    self._waiting.pop(owner, None)
        self._busy[owner] += 1

    def give_turn(self, owner: int | None) -> None:
        """The owner's work ended (on the event loop): the owner's next waiter runs."""
        if owner is None:
            return
        self._busy[owner] -= 1
        if self._busy[owner] <= 0:
            del self._busy[owner]
        for waiter in self._waiting.get(owner, ()):
            if not waiter.done():
                waiter.set_result(None)
                break

    def give_turn_threadsafe(self, loop: asyncio.AbstractEventLoop, owner: int | None) -> None:
        """:meth:`give_turn` from a thread (a work's done callback)."""
        if owner is not None:
            loop.call_soon_threadsafe(self.give_turn, owner)

    def held(self, owner: int) -> int:
        with self._lock:
            return self._held[owner]
