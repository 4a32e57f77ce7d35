"""Where the server expands users' templates: threads of their own, a bounded queue.

Issue 36: a template's expansion (a child process allowed ``EXPAND_SECONDS`` of CPU) ran
in the request threads, at a study's creation and again at every URDF read: 42 creations
of a slow template held AnyIO's 40 threads, and a study's read took 18.6 s instead of
0.15 s. Now a trial's URDF is expanded once and stored (``adservice.services.urdfs``),
and every expansion the server makes takes a place in this pool first:
``AD_EXPAND_THREADS`` places run (default 2), ``AD_EXPAND_QUEUE`` wait (default 16), and
a request that finds them all taken is answered 503 with ``Retry-After`` before it
stores anything. Waiting holds no thread; a place is held until its work ends, even if
the request that took it was cancelled meanwhile, so the count is what the threads owe.
"""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from types import TracebackType
from typing import Any, TypeVar

from adclient.templates import ByteLimit
from adservice.errors import BusyError, InvalidError
from adservice.fairness import OwnerShares, running_share

T = TypeVar("T")

RETRY_AFTER_SECONDS = 5
"""What a refused request is told to wait: an expansion takes a fraction of a second, a
hostile one up to ``EXPAND_SECONDS``; 5 s is also the SDK's longest backoff."""


@dataclass(frozen=True)
class Expansion:
    """A template at one trial's params: its URDF, or why it does not expand there."""

    urdf: str | None = None
    error: str | None = None

    def text(self) -> str:
        """The URDF; InvalidError with the template's message when it did not expand."""
        if self.urdf is None:
            raise InvalidError(f"the trial's template does not expand at its params: {self.error}")
        return self.urdf


@dataclass(frozen=True)
class UrdfLimits:
    """The server's bounds on template studies' URDFs (``AD_MAX_URDF_BYTES``,
    ``AD_MAX_ASK_URDF_BYTES``, ``AD_MAX_STUDY_URDF_BYTES``, ``AD_LEASE_EXPAND_SECONDS``)."""

    urdf_bytes: int = 2_000_000
    ask_bytes: int = 32_000_000
    study_bytes: int = 256_000_000
    lease_seconds: float = 5.0

    def per_urdf(self) -> ByteLimit:
        return ByteLimit(
            self.urdf_bytes, f"the limit of {self.urdf_bytes:,} bytes (AD_MAX_URDF_BYTES)"
        )

    def per_ask(self) -> ByteLimit:
        return ByteLimit(
            self.ask_bytes, f"the limit of {self.ask_bytes:,} bytes per ask (AD_MAX_ASK_URDF_BYTES)"
        )

    def study_room(self, study_stores: int) -> ByteLimit:
        """The bytes a study storing ``study_stores`` may still add (the URDF that reaches
        the study's limit is kept: the study then gets no new trial)."""
        return ByteLimit(
            self.study_bytes - study_stores,
            f"the limit of {self.study_bytes:,} bytes per study (AD_MAX_STUDY_URDF_BYTES)",
        )


@dataclass(frozen=True)
class Checks:
    """What each expansion is checked for: the links the study's task looks up, the
    bytes of one URDF and of the batch (strict), and the room left under the study's
    limit (kept until reached)."""

    links: tuple[tuple[str, str], ...] = ()
    per_urdf: ByteLimit | None = None
    together: ByteLimit | None = None
    room: ByteLimit | None = None


def expand_each(
    template: str, points: Sequence[Mapping[str, Any]], checks: Checks | None = None
) -> list[Expansion]:
    """Each point's expansion, in one child for them all (a child's start costs 25
    times an expansion of the example arm), each checked there as a study's creation
    checks its template (:func:`adclient.templates.expand_checked`: a robot the worker
    builds, with the task's links, within the byte limits). A point the child did not
    reach in its CPU time is failed with that limit; one after the URDFs kept reach the
    study's room, with that."""
    from adclient.templates import expand_checked

    checks = checks or Checks()
    expanded = expand_checked(
        template,
        points,
        links=checks.links,
        max_bytes=checks.per_urdf,
        max_total_bytes=checks.together,
    )
    kept = 0
    expansions = []
    for result in expanded:
        if result.urdf is None:
            expansions.append(Expansion(error=result.message()))
        elif checks.room is not None and kept >= checks.room.bytes:
            expansions.append(
                Expansion(
                    error=f"template, expanded: not kept: the study's URDFs reach "
                    f"{checks.room.text()}"
                )
            )
        else:
            kept += len(result.urdf.encode())
            expansions.append(Expansion(urdf=result.urdf))
    return expansions


class Place:
    """One expansion's place in the pool (:meth:`ExpansionPool.admit`): held until the
    work given to :meth:`run` ends, or until the ``with`` block ends if none was."""

    def __init__(self, pool: ExpansionPool, owner: int | None = None) -> None:
        self._pool = pool
        self._owner = owner
        self._running = False
        self._released = False

    def __enter__(self) -> Place:
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        error: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        if not self._running:
            self._release()

    async def run(self, work: Callable[[], T]) -> T:
        """``work()`` in an expansion thread (one work per place), once its owner's turn
        comes (``OwnerShares``: one owner's works never take every thread)."""
        assert not self._running, "a place runs one work"
        self._running = True
        shares, owner = self._pool.shares, self._owner
        try:
            await shares.take_turn(owner)
        except BaseException:
            self._release()
            raise
        loop = asyncio.get_running_loop()
        try:
            future: Future[T] = self._pool._executor.submit(self._pool._counted, work)
        except BaseException:
            shares.give_turn(owner)
            self._release()
            raise

        def ended(_: Future[T]) -> None:
            shares.give_turn_threadsafe(loop, owner)
            self._release()

        future.add_done_callback(ended)
        return await asyncio.wrap_future(future)

    def _release(self) -> None:
        with self._pool._lock:
            if self._released:
                return
            self._released = True
            self._pool._taken -= 1
        self._pool.shares.give_place(self._owner)


class ExpansionPool:
    """``threads`` expansions at a time, ``queue`` more waiting, no more; the server's
    ``limits`` on what they store, and each template study's expansions that failed or
    ran slow in a row (``failing``: what its backoff doubles with)."""

    def __init__(
        self,
        threads: int = 2,
        queue: int = 16,
        limits: UrdfLimits | None = None,
        per_owner: int | None = None,
    ) -> None:
        """``per_owner``: the places one study owner may hold (default: all of them)."""
        self.places = threads + queue
        self.shares = OwnerShares(
            places=per_owner or self.places,
            running=running_share(threads),
            what="template expansions",
            setting="AD_EXPAND_PER_OWNER",
        )
        self.limits = limits or UrdfLimits()
        self.failing: dict[int, int] = {}
        self._executor = ThreadPoolExecutor(max_workers=threads, thread_name_prefix="expand")
        self._lock = threading.Lock()
        self._taken = 0
        self._running = 0

    def admit(self, owner: int | None = None) -> Place:
        """A place for a study of ``owner`` (its token id; None: not counted), or
        BusyError (503) at once when every one is taken, RateLimitedError (429) when the
        owner holds its share."""
        with self._lock:
            if self._taken >= self.places:
                raise BusyError(
                    f"the server is busy expanding templates ({self.places} expansions "
                    f"running or waiting: AD_EXPAND_THREADS, AD_EXPAND_QUEUE): nothing was "
                    f"done; retry in {RETRY_AFTER_SECONDS} s",
                    retry_after=RETRY_AFTER_SECONDS,
                )
            self.shares.take_place(owner)
            self._taken += 1
        return Place(self, owner)

    async def run(self, work: Callable[[], T], owner: int | None = None) -> T:
        """``work()`` in an expansion thread, if a place is free (else BusyError)."""
        with self.admit(owner) as place:
            return await place.run(work)

    def counts(self) -> tuple[int, int]:
        """(running, waiting): the places taken now (``activedesign_pool_places``)."""
        with self._lock:
            return self._running, self._taken - self._running

    def _counted(self, work: Callable[[], T]) -> T:
        """``work()`` in an expansion thread, counted as running meanwhile."""
        with self._lock:
            self._running += 1
        try:
            return work()
        finally:
            with self._lock:
                self._running -= 1

    def shutdown(self) -> None:
        """Drop waiting expansions and wait for running ones (a child's limits bound them)."""
        self._executor.shutdown(wait=True, cancel_futures=True)
