"""Server CPU per ask+tell cycle: the ``adserver`` process's own CPU time, read from /proc
before and after the cycles, so other load on the machine moves it far less than it
moves cycles per second.

Each run starts a real ``adserver`` on a fresh SQLite file, warms it up, then ``--clients``
threads (httpx, a connection each) do ``--cycles`` ask+tell cycles in all (the
``random`` proposer, as bench/throughput.py). The medians over the runs are its result
lines; against other code, run it under ``bench/compare.py --baseline REV``.

    python bench/server_cpu.py [--runs 4] [--clients 8] [--cycles 1200]
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import threading
import time
from pathlib import Path

import httpx

from adclient.testing.figures import emit
from adclient.testing.servers import ServerProcess

BOX = {"type": "box", "params": [{"name": "x", "low": 0, "high": 1}]}


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def one_run(clients: int, cycles: int) -> tuple[float, float]:
    """(server ms of CPU per cycle, cycles per second) of one fresh server."""
    with tempfile.TemporaryDirectory() as temp:
        workdir = Path(temp)
        server = ServerProcess(
            database_url=f"sqlite:///{workdir / 'ad.db'}", workdir=workdir
        ).start()
        try:
            with httpx.Client(base_url=server.url, timeout=60) as http:
                body = {"name": "cpu", "space": BOX, "proposer": {"name": "random"}}
                study = http.post("/api/v1/studies", json=body).json()["id"]
                for _ in range(20):  # warm up: the study's configuration cached
                    trial = http.post(f"/api/v1/studies/{study}/ask", json={"count": 1})
                    tid = trial.json()["trials"][0]["id"]
                    http.post(f"/api/v1/trials/{tid}/tell", json={"value": 0.0})

            def client() -> None:
                with httpx.Client(base_url=server.url, timeout=60) as http:
                    for i in range(cycles // clients):
                        asked = http.post(f"/api/v1/studies/{study}/ask", json={"count": 1})
                        tid = asked.json()["trials"][0]["id"]
                        told = http.post(f"/api/v1/trials/{tid}/tell", json={"value": float(i)})
                        told.raise_for_status()

            assert server.process is not None
            pid = server.process.pid
            before, start = cpu_seconds(pid), time.perf_counter()
            threads = [threading.Thread(target=client) for _ in range(clients)]
            for thread in threads:
                thread.start()
            for thread in threads:
                thread.join()
            elapsed, used = time.perf_counter() - start, cpu_seconds(pid) - before
        finally:
            server.stop()
    done = clients * (cycles // clients)
    return 1000 * used / done, done / elapsed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=4)
    parser.add_argument("--clients", type=int, default=8)
    parser.add_argument("--cycles", type=int, default=1200)
    args = parser.parse_args()
    per_cycle, rates = [], []
    for run in range(args.runs):
        ms, rate = one_run(args.clients, args.cycles)
        per_cycle.append(ms)
        rates.append(rate)
        print(f"run {run + 1}: {ms:.2f} ms server CPU per cycle, {rate:.0f} cycles/s")
    shown = ", ".join(f"{v:.2f}" for v in per_cycle)
    print(f"{shown}; median {statistics.median(per_cycle):.2f} ms per cycle")
    emit("server CPU per cycle", statistics.median(per_cycle), higher_is_better=False, unit="ms")
    emit("cycles/s", statistics.median(rates), higher_is_better=True)


if __name__ == "__main__":
    main()
