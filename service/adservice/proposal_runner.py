"""Where model-based proposals run: threads of their own, entered one study at a time.

Issue 13: a qEI fit used to run in AnyIO's default thread pool (40 threads), which
also serves every sync route, and waited for its study's lock there; a burst of
heavy asks of one study held every thread, and leases, reads and ``/healthz`` of every
other study waited behind it. Now a proposal first waits for its study's turn on the
event loop (an ``asyncio.Lock``: waiting holds no thread), then computes in a
bounded pool used by proposals alone (``AD_PROPOSAL_THREADS``, default: the cores
this process may use). A study's turn ends when its thread is done, even if the
request was cancelled meanwhile, so one study never has two proposals computing in
this process; ``StudyLocks`` (taken inside the thread) keeps serving other
processes on PostgreSQL. The runner also holds each ask's time and memory budget.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
from collections.abc import Callable, Iterable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import TypeVar

T = TypeVar("T")


@dataclass(frozen=True)
class AskBudget:
    """What one ask may spend: seconds of search, and bytes of memory (None: no limit)."""

    seconds: float | None = None
    memory_bytes: int | None = None


def available_cores() -> int:
    """The cores this process may run on (its CPU affinity), not the machine's."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


@dataclass
class _Turn:
    lock: asyncio.Lock = field(default_factory=asyncio.Lock)
    users: int = 0


class ProposalRunner:
    def __init__(self, threads: int, budget: AskBudget | None = None) -> None:
        self.threads = threads
        self.budget = budget or AskBudget()
        self._executor = ThreadPoolExecutor(max_workers=threads, thread_name_prefix="propose")
        self._turns: dict[int, _Turn] = {}

    def busy(self, study_id: int) -> bool:
        """Whether a proposal of this study is computing or waiting its turn here."""
        return study_id in self._turns

    def free_first(self, study_ids: Iterable[int]) -> list[int]:
        """The studies in their order, those with no proposal under way first: a lease
        goes on to another study rather than wait behind a long ask."""
        ids = list(study_ids)
        return [i for i in ids if not self.busy(i)] + [i for i in ids if self.busy(i)]

    async def run(self, study_id: int, work: Callable[[], T]) -> T:
        """``work()`` in a proposal thread once this study's previous proposals are done."""
        turn = self._turns.setdefault(study_id, _Turn())
        turn.users += 1
        try:
            await turn.lock.acquire()
        except BaseException:
            self._leave(study_id, turn, release=False)
            raise
        try:
            future: Future[T] = self._executor.submit(work)
        except BaseException:
            self._leave(study_id, turn, release=True)
            raise
        loop = asyncio.get_running_loop()

        def done(_: Future[T]) -> None:
            with contextlib.suppress(RuntimeError):  # a closed loop: nobody waits for the turn
                loop.call_soon_threadsafe(self._leave, study_id, turn, True)

        future.add_done_callback(done)
        return await asyncio.wrap_future(future)

    def _leave(self, study_id: int, turn: _Turn, release: bool) -> None:
        if release:
            turn.lock.release()
        turn.users -= 1
        if turn.users == 0:
            del self._turns[study_id]

    def shutdown(self) -> None:
        """Drop queued proposals and wait for those computing (the time budget bounds them)."""
        self._executor.shutdown(wait=True, cancel_futures=True)
