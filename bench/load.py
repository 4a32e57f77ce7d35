"""Load: 32 simulated workers run a 10,000-trial managed study against one server, on a
SQLite file and on PostgreSQL, in the same run, side by side.

Each worker is a thread with its own HTTP connection doing what ``adworker`` does, minus
the physics: lease a job, send a heartbeat, compute a cheap score, tell it. The threads
are spread over a few client processes so the clients' own interpreter lock does not set
the pace. The server is a real ``adserver`` process; PostgreSQL is a throwaway cluster
(Debian's package, installed if missing; default durability: fsync and synchronous
commit on) started for the run.

Reported per database: trials per second, the 50th/99th-percentile latency of lease,
heartbeat and tell, non-2xx answers, and, read back from the server afterwards, trials
lost (acknowledged tells not stored as told, or trials never told), duplicated (a trial
leased twice or a trial number used twice) and stuck (not finished at the end).

With ``--adworkers process,ray`` the workers are real ``adworker`` programs instead, one
after the other against a fresh server each, side by side in the table: ``process`` is
``adworker --concurrency N`` (N worker processes), ``ray`` is ``adworker --ray local
--concurrency N`` (a local Ray cluster started by it, N Ray actors). Both score the
no-physics task with the same function (``adclient.testing.noop`` through ``--function``)
and log warnings only. Reported per arm: trials per second in the steady state (the tells
between the 10% and 90% marks, by the trials' own times: past the workers' staggered start),
from first lease to last tell, and the wall time with start-up; lost (trials of
the budget never stored complete, or stored with another value than the function's),
duplicated (a trial leased more than once, by its ``attempts``, or a number used twice),
stuck, and whether the server's ``/metrics`` at the end agree with its database (trials
by study and state, leases held, the queue, tells and leases answered); then the Ray arm's
throughput as a ratio of the process arm's.

Run: ``.venv/bin/python bench/load.py [--workers 32] [--trials 10000]
[--databases sqlite,postgresql] [--adworkers process,ray] [--json FILE]``.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections import Counter
from datetime import datetime
from pathlib import Path
from typing import Any

import sqlalchemy as sa

from adclient import Client
from adclient.testing.figures import emit
from adclient.testing.load import ENDPOINTS, create_study, run_load
from adclient.testing.metrics import Samples, in_database, scrape, trials_reported
from adclient.testing.noop import score_params as score
from adclient.testing.postgres import PostgresCluster
from adclient.testing.servers import ServerProcess
from adclient.testing.workers import ADWORKER

LEASE_ROUTE = (("method", "POST"), ("route", "/api/v1/jobs/lease"), ("status", "200"))
TELL_ROUTE = (("method", "POST"), ("route", "/api/v1/trials/{trial_id}/tell"), ("status", "200"))


def metrics_problems(samples: Samples, database_url: str, told: int, leased: int) -> list[str]:
    """Where the scrape disagrees with the database (counted with SQL, as the metrics'
    tests count) and with what the trials say was told and leased: an empty list when
    every metric agrees."""
    counts, leases = in_database(database_url)
    engine = sa.create_engine(database_url)
    try:
        with engine.connect() as connection:
            waiting = connection.execute(
                sa.text(
                    "SELECT coalesce(sum(s.max_trials - s.n_trials), 0) + (SELECT count(*) "
                    "FROM trials t JOIN studies q ON q.id = t.study_id "
                    "WHERE t.state = 'queued' AND q.state = 'running') "
                    "FROM studies s WHERE s.state = 'running' AND s.max_trials IS NOT NULL"
                )
            ).scalar_one()
    finally:
        engine.dispose()
    checks = {
        "activedesign_trials by study and state": (trials_reported(samples), counts),
        "activedesign_leases_active": (samples.get(("activedesign_leases_active", ())), leases),
        "activedesign_queue_depth{task=noop}": (
            # no series once no running study names the task: none waiting
            samples.get(("activedesign_queue_depth", (("task", "noop"),)), 0.0),
            waiting,
        ),
        "activedesign_tells_total": (samples.get(("activedesign_tells_total", ())), told),
        "tells answered 200 (http histogram)": (
            samples.get(("activedesign_http_request_duration_seconds_count", TELL_ROUTE)),
            told,
        ),
        "leases answered 200 (http histogram)": (
            samples.get(("activedesign_http_request_duration_seconds_count", LEASE_ROUTE)),
            leased,
        ),
    }
    return [
        f"{what}: /metrics {got} != {want}" for what, (got, want) in checks.items() if got != want
    ]


def run_adworkers(
    database_url: str, workdir: Path, kind: str, *, workers: int, trials: int, limit_s: float
) -> dict[str, Any]:
    """One real ``adworker`` (``kind``: process or ray) with ``workers`` workers runs the
    load study to its end against a fresh server; what the trials and /metrics say."""
    server = ServerProcess(
        database_url=database_url, workdir=workdir, env={"AD_LEASE_SECONDS": "60"}
    ).start()
    log_path = workdir / f"adworker-{kind}.log"
    try:
        study_id = create_study(server.url, trials)
        command = [
            str(ADWORKER),
            *("--server", server.url, "--worker-id", kind, "--concurrency", str(workers)),
            *("--poll", "0.2", "--log-level", "warning"),
            *("--function", "adclient.testing.noop:score", "--task", "noop"),
            *(["--ray", "local"] if kind == "ray" else []),
        ]
        environment = {key: value for key, value in os.environ.items() if key != "AD_TOKEN"}
        started = time.perf_counter()
        with log_path.open("wb") as log:
            worker = subprocess.Popen(
                command, stdout=log, stderr=subprocess.STDOUT, env=environment
            )
        try:
            deadline = time.monotonic() + limit_s
            last_report = time.monotonic()
            with Client(server.url, timeout=60) as sdk:
                while time.monotonic() < deadline and worker.poll() is None:
                    info = sdk.study_info(study_id)
                    if info.state != "running":
                        break
                    if time.monotonic() - last_report >= 15:
                        last_report = time.monotonic()
                        seconds = time.perf_counter() - started
                        print(
                            f"  {kind}: {info.n_complete} of {trials} complete after "
                            f"{seconds:.0f} s ({info.n_complete / seconds:.1f} trials/s with "
                            "start-up)",
                            flush=True,
                        )
                    time.sleep(1.0)
            elapsed = time.perf_counter() - started
        finally:
            worker.send_signal(signal.SIGTERM)  # finish, report and go; the cluster too
            try:
                exit_code = worker.wait(timeout=120)
            except subprocess.TimeoutExpired:
                worker.send_signal(signal.SIGTERM)
                exit_code = worker.wait(timeout=120)
        with Client(server.url, timeout=120) as sdk:  # pages through every trial
            stored = [trial.model_dump(mode="json") for trial in sdk.trials(study_id)]
            study = sdk.study_info(study_id).model_dump(mode="json")
        samples = scrape(server.url)
    finally:
        server.stop()

    complete = [trial for trial in stored if trial["state"] == "complete"]
    wrong = sum(1 for trial in complete if trial["value"] != score(trial["params"]))
    number_counts = Counter(trial["number"] for trial in stored)
    duplicated = sum(trial["attempts"] - 1 for trial in stored if trial["attempts"] > 1) + sum(
        n - 1 for n in number_counts.values() if n > 1
    )
    stuck = sum(1 for trial in stored if trial["state"] not in ("complete", "failed"))
    failed = sum(1 for trial in stored if trial["state"] == "failed")
    starts = sorted(datetime.fromisoformat(trial["started_at"]) for trial in complete)
    ends = sorted(datetime.fromisoformat(trial["finished_at"]) for trial in complete)
    working = (ends[-1] - starts[0]).total_seconds() if complete else math.nan
    # Steady state: the tells between the 10% and the 90% marks, past the workers'
    # staggered start (processes spawned, actors placed) and the last stragglers.
    low, high = len(ends) // 10, len(ends) * 9 // 10
    steady = (ends[high] - ends[low]).total_seconds() if high > low else math.nan
    told = len(complete) + failed
    problems = metrics_problems(
        samples, database_url, told=told, leased=sum(t["attempts"] for t in stored)
    )
    return {
        "adworker": kind,
        "trials": trials,
        "workers": workers,
        "seconds": round(elapsed, 1),
        "working_seconds": round(working, 1),
        "trials_per_s": round((high - low) / steady, 1) if high > low else 0.0,
        "trials_per_s_first_to_last": round(len(complete) / working, 1) if complete else 0.0,
        "trials_per_s_with_startup": round(len(complete) / elapsed, 1),
        "stored": len(stored),
        "complete": len(complete),
        "failed": failed,
        "study_state": study["state"],
        "lost": trials - len(complete) - failed + wrong,
        "duplicated": duplicated,
        "stuck": stuck,
        "metrics_consistent": not problems,
        "metrics_problems": problems,
        "tells_total": samples.get(("activedesign_tells_total", ())),
        "exit_code": exit_code,
        "log_tail": log_path.read_text(errors="replace").splitlines()[-5:],
    }


LOST_ROW = (
    "lost / duplicated / stuck",
    lambda r: f"{r['lost']} / {r['duplicated']} / {r['stuck']}",
)


def print_markdown(results: dict[str, dict[str, Any]], rows: list[tuple[str, Any]]) -> None:
    """A Markdown table: a column per result, a row per (label, cell of a result)."""
    names = list(results)
    table = [
        ["", *names],
        *([label, *(str(cell(results[n])) for n in names)] for label, cell in rows),
    ]
    widths = [max(len(row[i]) for row in table) for i in range(len(table[0]))]
    for index, row in enumerate(table):
        print("| " + " | ".join(f"{text:{widths[i]}}" for i, text in enumerate(row)) + " |")
        if index == 0:
            print("|" + "|".join("-" * (width + 2) for width in widths) + "|")


def print_table(results: dict[str, dict[str, Any]]) -> None:
    print_markdown(
        results,
        [
            ("trials stored / complete", lambda r: f"{r['stored']} / {r['complete']}"),
            ("wall time (s)", lambda r: r["seconds"]),
            ("throughput (trials/s)", lambda r: r["trials_per_s"]),
            *[
                (
                    f"{endpoint} p50 / p99 (ms)",
                    lambda r, e=endpoint: (
                        f"{r['latency_ms'][e]['p50']} / {r['latency_ms'][e]['p99']}"
                    ),
                )
                for endpoint in ENDPOINTS
            ],
            ("non-2xx answers", lambda r: sum(r["errors"].values())),
            LOST_ROW,
            ("study state", lambda r: r["study_state"]),
        ],
    )


def print_adworker_table(results: dict[str, dict[str, Any]]) -> None:
    print_markdown(
        results,
        [
            ("trials stored / complete", lambda r: f"{r['stored']} / {r['complete']}"),
            ("wall time with start-up (s)", lambda r: r["seconds"]),
            ("first lease to last tell (s)", lambda r: r["working_seconds"]),
            ("throughput, first to last (trials/s)", lambda r: r["trials_per_s_first_to_last"]),
            ("throughput, 10% to 90% (trials/s)", lambda r: r["trials_per_s"]),
            LOST_ROW,
            (
                "/metrics agree with the database",
                lambda r: "yes" if r["metrics_consistent"] else "NO",
            ),
            ("study state / adworker exit", lambda r: f"{r['study_state']} / {r['exit_code']}"),
        ],
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--workers", type=int, default=32)
    parser.add_argument("--trials", type=int, default=10_000)
    parser.add_argument("--processes", type=int, default=4, help="client processes")
    parser.add_argument("--databases", default="sqlite,postgresql")
    parser.add_argument(
        "--adworkers",
        default="",
        help="real adworker arms instead of simulated workers: process, ray or both",
    )
    parser.add_argument("--limit", type=float, default=1800.0, help="seconds per database")
    parser.add_argument("--json", type=Path, help="also write the figures here")
    args = parser.parse_args()
    kinds = [kind for kind in args.adworkers.split(",") if kind]
    if any(kind not in ("process", "ray") for kind in kinds):
        parser.error(f"--adworkers takes process and ray, not {args.adworkers!r}")

    results: dict[str, dict[str, Any]] = {}
    with tempfile.TemporaryDirectory(prefix="ad-load-") as tmp:
        for database in args.databases.split(","):
            if database not in ("sqlite", "postgresql"):
                parser.error(f"unknown database {database!r}")
            for kind in kinds or ["simulated"]:
                name = database if not kinds else f"{kind} ({database})"
                workdir = Path(tmp) / f"{database}-{kind}"
                workdir.mkdir()
                print(f"{name}: {args.workers} workers, {args.trials} trials ...", flush=True)
                with contextlib.ExitStack() as stack:
                    if database == "sqlite":
                        url = f"sqlite:///{workdir / 'load.db'}"
                    else:
                        cluster = stack.enter_context(PostgresCluster.start(durable=True))
                        url = cluster.create_database("load")
                    if kinds:
                        results[name] = run_adworkers(
                            url,
                            workdir,
                            kind,
                            workers=args.workers,
                            trials=args.trials,
                            limit_s=args.limit,
                        )
                    else:
                        results[name] = run_load(
                            url,
                            workdir,
                            workers=args.workers,
                            trials=args.trials,
                            processes=args.processes,
                            limit_s=args.limit,
                        )
                print(json.dumps(results[name]), flush=True)
                emit(
                    f"{name} throughput",
                    results[name]["trials_per_s"],
                    higher_is_better=True,
                    unit="trials/s",
                )
                for endpoint in ("lease", "tell") if not kinds else ():
                    for q in ("p50", "p99"):
                        latency = results[name]["latency_ms"][endpoint][q]
                        emit(f"{name} {endpoint} {q}", latency, higher_is_better=False, unit="ms")
    print()
    if kinds:
        print_adworker_table(results)
        for database in args.databases.split(","):
            arms = results.get(f"process ({database})"), results.get(f"ray ({database})")
            if arms[0] and arms[1] and arms[0]["trials_per_s"]:
                ratio = arms[1]["trials_per_s"] / arms[0]["trials_per_s"]
                print(f"\n{database}: Ray / process throughput {ratio:.3f} (goal: >= 0.8)")
                results[f"ray/process ({database})"] = {"throughput_ratio": round(ratio, 3)}
    else:
        print_table(results)
    if args.json:
        args.json.write_text(json.dumps(results, indent=2) + "\n")
    failed = any(
        r.get("lost") or r.get("duplicated") or r.get("stuck") or not r.get("metrics_consistent", 1)
        for r in results.values()
    )
    sys.exit(1 if failed else 0)


if __name__ == "__main__":
    main()
