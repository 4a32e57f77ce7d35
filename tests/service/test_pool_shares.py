"""One owner's share of the expansion pool (adservice.fairness): its places past
``per_owner`` are refused (429, naming AD_EXPAND_PER_OWNER) while other owners find
theirs, and its works run on all but one thread, so another owner's work runs while
its own wait. The real pool and its threads; the works wait on events, so what is
checked is the order of events."""

from __future__ import annotations

import asyncio
import threading

import pytest

from adservice.errors import RateLimitedError
from adservice.expansions import ExpansionPool
from adservice.fairness import running_share


def test_running_share_leaves_one_worker_to_the_others() -> None:
    assert [running_share(workers) for workers in (1, 2, 3, 8)] == [1, 1, 2, 7]


def test_an_owners_expansions_keep_to_their_share_and_others_run_beside_them() -> None:
    pool = ExpansionPool(threads=2, queue=8, per_owner=3)
    release = threading.Event()
    started: list[str] = []

    def blocked(name: str) -> str:
        started.append(name)
        release.wait(30)
        return name

    async def scenario() -> None:
        alice = [asyncio.ensure_future(pool.run(lambda n=n: blocked(f"a{n}"), 1)) for n in range(3)]
        await asyncio.sleep(0.2)
        assert started == ["a0"], started  # one of alice's runs; two wait for her turn
        assert pool.counts() == (1, 2)
        with pytest.raises(RateLimitedError, match="AD_EXPAND_PER_OWNER"):
            pool.admit(1)
        # bob's work runs on the other thread at once, while alice's wait
        assert await asyncio.wait_for(pool.run(lambda: "b", 2), 10) == "b"
        assert started == ["a0"]
        release.set()
        assert await asyncio.gather(*alice) == ["a0", "a1", "a2"]
        assert pool.counts() == (0, 0)
        # an ownerless study (auth off) is not counted
        assert await pool.run(lambda: "open") == "open"

    try:
        asyncio.run(scenario())
    finally:
        release.set()
        pool.shutdown()


def test_a_cancelled_wait_for_its_owners_turn_gives_its_place_back() -> None:
    pool = ExpansionPool(threads=2, queue=8, per_owner=2)
    release = threading.Event()

    async def scenario() -> None:
        running = asyncio.ensure_future(pool.run(lambda: release.wait(30), 1))
        waiting = asyncio.ensure_future(pool.run(lambda: "never", 1))
        await asyncio.sleep(0.2)
        assert pool.counts() == (1, 1)
        waiting.cancel()
        await asyncio.sleep(0.05)
        assert pool.counts() == (1, 0)
        pool.admit(1).__exit__(None, None, None)  # the owner has a place again
        release.set()
        await running

    try:
        asyncio.run(scenario())
    finally:
        release.set()
        pool.shutdown()
