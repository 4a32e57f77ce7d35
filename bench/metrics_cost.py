"""What the HTTP-duration instrumentation (adservice.metrics.HttpMetrics) costs the server.

Two measures:
- server CPU per ask+tell cycle: real ``adserver`` processes on fresh SQLite files, with
  the instrumentation and without it (the same program, launched with ``install_metrics``
  replaced by one that adds no middleware), in alternating runs; each run warms up, then
  its client threads (httpx, a connection each) do the cycles while the server's
  utime+stime is read from /proc before and after;
- the layer alone, in process: a request through ``HttpMetrics`` around an ASGI app that
  answers at once, against that app bare (the difference is the layer's own time);
- a scrape: ``GET /metrics`` of a server whose SQLite file holds ``--scrape-trials``
  trials in 100 studies (written straight into it), the server's CPU per scrape.

    python bench/metrics_cost.py [--runs 5] [--clients 4] [--cycles 1500]
    python bench/metrics_cost.py --runs 0 --scrape-trials 100000
"""

from __future__ import annotations

import argparse
import asyncio
import os
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

import httpx
import sqlalchemy as sa
from starlette.types import Message, Receive, Scope, Send

from adclient.testing.servers import ServerProcess
from adservice.metrics import HttpMetrics, Metrics
from adservice.models import TrialRow

WITHOUT = (
    "import adservice.app, adservice.metrics, adservice.cli;"
    "adservice.app.install_metrics = "
    "lambda app: setattr(app.state, 'metrics', adservice.metrics.Metrics());"
    "adservice.cli.main()"
)
"""adserver with /metrics but no per-request layer."""


def server_cpu(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().split(")")[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def cycles(url: str, study: int, clients: int, count: int) -> None:
    def client() -> None:
        with httpx.Client(base_url=url, timeout=60) as http:
            for _ in range(count):
                asked = http.post(f"/api/v1/studies/{study}/ask", json={"count": 1})
                trial = asked.json()["trials"][0]
                told = http.post(f"/api/v1/trials/{trial['id']}/tell", json={"value": 1.0})
                assert told.status_code == 200, told.text

    threads = [threading.Thread(target=client) for _ in range(clients)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()


def one_run(instrumented: bool, clients: int, count: int) -> tuple[float, float]:
    """Server CPU microseconds per cycle, and cycles per second."""
    work = Path(tempfile.mkdtemp())
    program = None if instrumented else [sys.executable, "-c", WITHOUT]
    server = ServerProcess(database_url=f"sqlite:///{work / 'ad.db'}", workdir=work)
    if program is not None:
        server.program = program
    server.start()
    assert server.process is not None
    try:
        with httpx.Client(base_url=server.url) as http:
            body = {
                "name": "cost",
                "space": {"type": "box", "params": [{"name": "x", "low": 0, "high": 1}]},
                "proposer": {"name": "random"},
            }
            study = http.post("/api/v1/studies", json=body).json()["id"]
            samples = http.get("/metrics").text
        assert ('route="/api/v1/studies"' in samples) == instrumented
        cycles(server.url, study, clients, count // 5)  # warm up
        before, start = server_cpu(server.process.pid), time.perf_counter()
        cycles(server.url, study, clients, count)
        cpu, wall = server_cpu(server.process.pid) - before, time.perf_counter() - start
    finally:
        server.stop()
    total = clients * count
    return cpu / total * 1e6, total / wall


def layer_alone(requests: int = 200_000) -> tuple[float, float]:
    """Microseconds per request through a bare app, and through HttpMetrics around it."""

    async def answer(scope: Scope, receive: Receive, send: Send) -> None:
        await send({"type": "http.response.start", "status": 200, "headers": []})
        await send({"type": "http.response.body", "body": b""})

    async def discard(message: Message) -> None:
        return None

    async def receive() -> Message:
        return {"type": "http.request", "body": b""}

    scope: Scope = {"type": "http", "method": "POST", "path": "/api/v1/trials/1/tell"}

    async def timed(app: object) -> float:
        start = time.perf_counter()
        for _ in range(requests):
            await app(scope, receive, discard)  # type: ignore[operator]
        return (time.perf_counter() - start) / requests * 1e6

    bare = min(asyncio.run(timed(answer)) for _ in range(3))
    wrapped = min(asyncio.run(timed(HttpMetrics(answer, Metrics()))) for _ in range(3))
    return bare, wrapped


def scrape_cost(trials: int, scrapes: int = 10) -> tuple[float, int]:
    """Server CPU milliseconds per scrape, and the answer's bytes."""
    work = Path(tempfile.mkdtemp())
    url = f"sqlite:///{work / 'ad.db'}"
    server = ServerProcess(database_url=url, workdir=work).start()
    assert server.process is not None
    try:
        with httpx.Client(base_url=server.url, timeout=600) as http:
            space = {"type": "box", "params": [{"name": "x", "low": 0, "high": 1}]}
            ids = [
                http.post(
                    "/api/v1/studies",
                    json={"name": f"s{i}", "space": space, "proposer": {"name": "random"}},
                ).json()["id"]
                for i in range(100)
            ]
            states = ["complete", "complete", "complete", "failed", "running"]
            rows = [
                {
                    "study_id": ids[n % len(ids)],
                    "number": n // len(ids),
                    "state": states[n % len(states)],
                    "vector": [0.5],
                    "params": {"x": 0.5},
                    "metrics": {},
                    "info": {},
                    "attempts": 1,
                }
                for n in range(trials)
            ]
            engine = sa.create_engine(url)
            with engine.begin() as connection:
                connection.execute(sa.insert(TrialRow), rows)
            engine.dispose()
            http.get("/metrics")
            before = server_cpu(server.process.pid)
            for _ in range(scrapes):
                size = len(http.get("/metrics").content)
            cpu = server_cpu(server.process.pid) - before
    finally:
        server.stop()
    return cpu / scrapes * 1e3, size


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--runs", type=int, default=5, help="pairs of runs, alternating")
    parser.add_argument("--clients", type=int, default=4)
    parser.add_argument("--cycles", type=int, default=1500, help="per client and run")
    parser.add_argument("--scrape-trials", type=int, default=0, help="also time a scrape")
    args = parser.parse_args()
    results: dict[bool, list[tuple[float, float]]] = {True: [], False: []}
    for index in range(args.runs):
        for instrumented in (True, False) if index % 2 == 0 else (False, True):
            result = one_run(instrumented, args.clients, args.cycles)
            results[instrumented].append(result)
            label = "with" if instrumented else "without"
            print(f"run {index + 1} {label:>7}: {result[0]:7.1f} us CPU/cycle {result[1]:6.1f}/s")
    for instrumented in (True, False) if args.runs else ():
        cpu = [cpu for cpu, _ in results[instrumented]]
        rate = [rate for _, rate in results[instrumented]]
        label = "with" if instrumented else "without"
        print(
            f"{label:>7}: median {statistics.median(cpu):.1f} us CPU/cycle "
            f"(runs {min(cpu):.1f} to {max(cpu):.1f}), "
            f"median {statistics.median(rate):.1f} cycles/s"
        )
    if args.runs:
        difference = statistics.median(c for c, _ in results[True]) - statistics.median(
            c for c, _ in results[False]
        )
        print(f"difference of medians: {difference:+.1f} us CPU per cycle (two requests)")
    bare, wrapped = layer_alone()
    print(
        f"layer alone: {bare:.2f} us bare, {wrapped:.2f} us wrapped, "
        f"{wrapped - bare:.2f} us per request"
    )
    if args.scrape_trials:
        per_scrape, size = scrape_cost(args.scrape_trials)
        print(f"scrape of {args.scrape_trials} trials: {per_scrape:.1f} ms CPU, {size} bytes")


if __name__ == "__main__":
    main()
