"""Issue 13: lease latency of one study, alone and while another study's heavy ask computes.

A real ``adserver`` (SQLite file, loopback HTTP). Study A is ``qei`` on a box of
``--dim`` params holding ``--told`` observations; study B is managed (a task) with the
``random`` proposer. Each round times ``--leases`` concurrent leases of B (every one
a thread with its own connection) and a few ``/healthz``: first alone, then while one
``ask`` of ``--count`` points of A computes (started a second earlier; the round
checks that it was still computing when the last lease was answered) with
``--waiting`` more asks of A queued behind it. Printed: the
median and p95 lease latency in each case, their ratio, and the heavy ask's duration.
Goal (issue 13): the p95 of B's leases and of ``/healthz`` during A's ask under a fifth
of that ask (tests/service/test_proposal_isolation.py checks that every one is answered
while A's ask computes, not how fast).
Before issue 13 every fit held one process-wide lock and waited for it in the request
thread pool: 40 leases during a 35 s ask took 41 to 44 s.

Run: ``.venv/bin/python bench/ask_isolation.py [--rounds 3] [--dim 96] [--count 16]``.
"""

from __future__ import annotations

import argparse
import tempfile
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import httpx
import numpy as np

from adclient.testing.isolation import heavy_study, managed_study, waiting_asks
from adclient.testing.servers import ServerProcess

GOAL = 0.2
"""The p95 of B's leases and of /healthz during A's ask, as a share of that ask."""


def burst(url: str, leases: int) -> tuple[list[float], list[float], float]:
    """Latencies of ``leases`` concurrent leases and 5 /healthz, and when the last ended."""

    def call(index: int) -> tuple[float, float]:
        with httpx.Client(base_url=url, timeout=600) as http:
            started = time.monotonic()
            if index < leases:
                response = http.post("/api/v1/jobs/lease", json={"worker_id": f"w{index}"})
            else:
                response = http.get("/healthz")
            response.raise_for_status()
            return time.monotonic() - started, time.monotonic()

    with ThreadPoolExecutor(max_workers=leases + 5) as pool:
        results = list(pool.map(call, range(leases + 5)))
    seconds = [r[0] for r in results]
    return seconds[:leases], seconds[leases:], max(r[1] for r in results)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--dim", type=int, default=96)
    parser.add_argument("--told", type=int, default=40)
    parser.add_argument("--count", type=int, default=16)
    parser.add_argument("--leases", type=int, default=40)
    parser.add_argument("--waiting", type=int, default=45, help="asks queued behind A's")
    args = parser.parse_args()

    with tempfile.TemporaryDirectory() as workdir:
        server = ServerProcess(
            database_url=f"sqlite:///{Path(workdir) / 'isolation.db'}",
            workdir=Path(workdir),
            env={"AD_ASK_SECONDS": "600"},
        ).start()
        try:
            with httpx.Client(base_url=server.url, timeout=600) as http:
                managed_study(http)
                burst(server.url, 4)  # warm: imports, the study's config
                heavy = [
                    heavy_study(http, f"A{r}", args.dim, args.told, args.count)
                    for r in range(args.rounds)
                ]
            alone: list[float] = []
            during: list[float] = []
            health_alone: list[float] = []
            health_during: list[float] = []
            asks: list[float] = []
            for study_id in heavy:
                lease_s, health_s, _ = burst(server.url, args.leases)
                alone += lease_s
                health_alone += health_s
                outcome: dict[str, float] = {}

                def ask(study_id: int = study_id, outcome: dict[str, float] = outcome) -> None:
                    with httpx.Client(base_url=server.url, timeout=600) as http:
                        started = time.monotonic()
                        response = http.post(
                            f"/api/v1/studies/{study_id}/ask", json={"count": args.count}
                        )
                        response.raise_for_status()
                        outcome["seconds"] = time.monotonic() - started
                        outcome["ended"] = time.monotonic()

                thread = threading.Thread(target=ask)
                thread.start()
                time.sleep(0.5)
                unlimited = httpx.Limits(max_connections=None)
                with httpx.Client(base_url=server.url, timeout=600, limits=unlimited) as http:
                    queued, statuses = waiting_asks(http, study_id, args.waiting)
                    time.sleep(0.5)
                    lease_s, health_s, last = burst(server.url, args.leases)
                    thread.join()
                    for waiting in queued:
                        waiting.join()
                assert statuses == [409] * args.waiting, statuses
                if last > outcome["ended"]:
                    print("warning: the heavy ask ended before the leases; use a larger --count")
                during += lease_s
                health_during += health_s
                asks.append(outcome["seconds"])
        finally:
            server.stop()

    def line(name: str, values: list[float]) -> str:
        return (
            f"{name}: median {np.median(values) * 1000:.0f} ms, "
            f"p95 {np.percentile(values, 95) * 1000:.0f} ms"
        )

    print(
        f"{args.rounds} rounds of {args.leases} concurrent leases of study B (random, managed) "
        f"and 5 /healthz; study A: qei, {args.dim} params, {args.told} observations, "
        f"one ask of {args.count} and {args.waiting} asks queued behind it"
    )
    print(line("B's leases alone", alone))
    print(line("B's leases during A's ask", during))
    print(line("/healthz alone", health_alone))
    print(line("/healthz during A's ask", health_during))
    print(
        "ratio during/alone: median "
        f"{np.median(during) / np.median(alone):.2f}, "
        f"p95 {np.percentile(during, 95) / np.percentile(alone, 95):.2f}"
    )
    share = float(np.percentile(during, 95) / np.median(asks))
    health_share = float(np.percentile(health_during, 95) / np.median(asks))
    print(
        f"A's ask: median {np.median(asks):.1f} s (p95 of B's leases during it: "
        f"{share * 100:.1f}% of it, of /healthz: {health_share * 100:.1f}%)"
    )
    met = max(share, health_share) < GOAL
    print(f"goal (both p95 under {GOAL:.0%} of A's ask): {'met' if met else 'missed'}")


if __name__ == "__main__":
    main()
