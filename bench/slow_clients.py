"""/healthz latency while slow or oversized clients attack a real ``adserver``.

Each attack runs for ``--seconds`` while a probe asks ``GET /healthz`` on a fresh
connection every 0.2 s; the table gives the probe's median and worst latency, their ratio
to a run with no attack, how many attacking connections the server closed, and the
server's resident memory at the end.
Attacks: one 100 MB header; 250 slowloris connections (a header line a second, never
finished); 100 slow bodies (a byte a second); 250 idle connections. ``--unprotected``
runs the same app under plain ``uvicorn.run`` as before issue 13 (httptools, no header
cap or timeouts) for comparison.
Goal (issue 13): no probe slower than 5 s under any attack; the last column says whether
each attack met it (tests/service/test_server_limits.py checks the refusals and closes,
not the time).
Run: ``.venv/bin/python bench/slow_clients.py [--seconds 15] [--unprotected]``.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path

import httpx

from adclient.testing.attacks import (
    Attack,
    big_header,
    healthz_seconds,
    idle,
    slow_body,
    slowloris,
)
from adclient.testing.servers import free_port

GOAL_S = 5.0
"""No probe under attack slower than this (a 100 MB header once froze the server for 12 to
23 s)."""
UNPROTECTED = (
    "import sys, uvicorn\n"
    "from adservice.app import create_app\n"
    "from adservice.settings import Settings\n"
    "app = create_app(Settings(database_url=sys.argv[1], body_timeout=1e9))\n"
    "uvicorn.run(app, host='127.0.0.1', port=int(sys.argv[2]), log_level='warning')\n"
)


def start_server(
    workdir: Path, *, unprotected: bool = False, env: dict[str, str] | None = None
) -> tuple[subprocess.Popen[bytes], int]:
    """A real server on a free port (``adserver``, or the app under plain uvicorn)."""
    port = free_port()
    database_url = f"sqlite:///{workdir / 'slow.db'}"
    python = Path(sys.executable)
    if unprotected:
        command = [str(python), "-c", UNPROTECTED, database_url, str(port)]
    else:
        command = [str(python.with_name("adserver")), "--port", str(port), "--log-level"]
        command += ["warning", "--database-url", database_url]
    process = subprocess.Popen(
        command,
        cwd=workdir,
        env={**os.environ, "AD_ARTIFACT_DIR": str(workdir / "artifacts"), **(env or {})},
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    url = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        if process.poll() is not None:
            raise RuntimeError("server exited early")
        try:
            if httpx.get(f"{url}/healthz", timeout=1.0).status_code == 200:
                return process, port
        except httpx.TransportError:
            time.sleep(0.1)
    process.kill()
    raise RuntimeError("server did not start")


def rss_mb(pid: int) -> float:
    """The process's resident memory now (Linux)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


ATTACKS: dict[str, Callable[[int, threading.Event], Attack] | None] = {
    "none": None,
    "100 MB header": big_header,
    "250 slowloris": slowloris,
    "100 slow bodies": slow_body,
    "250 idle": idle,
}


def measure(
    port: int, attack: Callable[[int, threading.Event], Attack] | None, seconds: float
) -> tuple[list[float], Attack]:
    """Probe latencies (s) during ``seconds`` of ``attack``, and what the attack saw."""
    stop = threading.Event()
    result: list[Attack] = []
    thread = None
    if attack is not None:
        thread = threading.Thread(target=lambda: result.append(attack(port, stop)), daemon=True)
        thread.start()
        time.sleep(0.5)  # let it open its connections
    latencies = []
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        latencies.append(healthz_seconds(port))
        time.sleep(0.2)
    stop.set()
    if thread is not None:
        thread.join(timeout=180)
    return latencies, (result[0] if result else Attack())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=15.0, help="per attack")
    parser.add_argument("--unprotected", action="store_true", help="plain uvicorn, no limits")
    parser.add_argument("--header-timeout", default="5", help="AD_HEADER_TIMEOUT for adserver")
    parser.add_argument("--body-timeout", default="5", help="AD_BODY_TIMEOUT for adserver")
    args = parser.parse_args()
    env = {"AD_HEADER_TIMEOUT": args.header_timeout, "AD_BODY_TIMEOUT": args.body_timeout}
    label = "plain uvicorn (no limits)" if args.unprotected else f"adserver with {env}"
    print(f"{label}; {args.seconds:g} s per attack; /healthz every 0.2 s on a new connection")
    print(
        f"{'attack':<17}{'probes':>7}{'p50 ms':>9}{'max ms':>10}{'p50 x':>7}{'max x':>8}"
        f"{'closed':>10}{'first close s':>15}{'RSS MB':>8}  {'answers':<14}goal"
    )
    base_p50 = base_max = 0.0
    for name, attack in ATTACKS.items():
        with tempfile.TemporaryDirectory() as temp:
            process, port = start_server(Path(temp), unprotected=args.unprotected, env=env)
            try:
                latencies, seen = measure(port, attack, args.seconds)
                rss = rss_mb(process.pid)
            finally:
                process.kill()
                process.wait()
        p50, worst = statistics.median(latencies), max(latencies)
        if attack is None:
            base_p50, base_max = p50, worst
        first = "-" if seen.first_close_s is None else f"{seen.first_close_s:.1f}"
        goal = "met" if worst < GOAL_S else "missed"
        print(
            f"{name:<17}{len(latencies):>7}{p50 * 1e3:>9.1f}{worst * 1e3:>10.1f}"
            f"{p50 / base_p50:>7.1f}{worst / base_max:>8.1f}"
            f"{f'{seen.closed}/{seen.opened}':>10}{first:>15}{rss:>8.0f}  "
            f"{seen.answers or '-':<14}{goal}",
            flush=True,
        )


if __name__ == "__main__":
    main()
