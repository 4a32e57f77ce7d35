"""Ask+tell cycles per second: activedesign over HTTP vs Optuna's RDB storage on SQLite.

Both run in this one command on this machine, with the same number of concurrent
clients and the same cheap objective, each on a fresh SQLite file:
- activedesign: a real ``adserver`` process; every client is a thread with its own
  HTTP connection doing ``POST ask`` then ``POST tell`` (the ``random`` proposer);
- Optuna: every client is a thread doing ``study.ask()`` then ``study.tell()`` on one
  ``RDBStorage`` (in-process: no HTTP at all, Optuna's own distributed setup).

Afterwards each store is read back: every told value must be there exactly once. The
exit status is 1 where activedesign lost, duplicated or refused a cycle or said "database
is locked" (its result lines are printed first).
Run: ``.venv/bin/python bench/throughput.py [--clients 8] [--cycles 150]``.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import threading
import time
from collections import Counter
from pathlib import Path

import httpx

from adclient import Client
from adclient.testing.figures import emit
from adclient.testing.servers import ServerProcess


def run_activedesign(workdir: Path, clients: int, cycles: int) -> dict[str, float]:
    server = ServerProcess(database_url=f"sqlite:///{workdir / 'ad.db'}", workdir=workdir).start()
    errors: Counter[str] = Counter()
    told: dict[int, float] = {}
    guard = threading.Lock()
    try:
        with httpx.Client(base_url=server.url, timeout=60) as http:
            study = http.post(
                "/api/v1/studies",
                json={
                    "name": "throughput",
                    "space": {"type": "box", "params": [{"name": "x", "low": 0, "high": 1}]},
                    "proposer": {"name": "random"},
                },
            ).json()

        def client(index: int) -> None:
            with httpx.Client(base_url=server.url, timeout=60) as http:
                for i in range(cycles):
                    asked = http.post(f"/api/v1/studies/{study['id']}/ask", json={"count": 1})
                    if asked.status_code != 200:
                        errors[asked.text[:80]] += 1
                        continue
                    trial = asked.json()["trials"][0]
                    value = index * 1e6 + i
                    tell = http.post(f"/api/v1/trials/{trial['id']}/tell", json={"value": value})
                    if tell.status_code != 200:
                        errors[tell.text[:80]] += 1
                        continue
                    with guard:
                        told[trial["id"]] = value

        start = time.perf_counter()
        threads = [threading.Thread(target=client, args=(i,)) for i in range(clients)]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
        elapsed = time.perf_counter() - start
        with Client(server.url, timeout=60) as sdk:  # pages through every trial
            stored = [trial.model_dump(mode="json") for trial in sdk.trials(study["id"])]
    finally:
        server.stop()
    log = server.log_path.read_text()
    stored_values = {t["id"]: t["value"] for t in stored if t["state"] == "complete"}
    return {
        "cycles": len(told),
        "seconds": elapsed,
        "rate": len(told) / elapsed,
        "lost": sum(1 for k, v in told.items() if stored_values.get(k) != v),
        "duplicated": len(stored) - len({t["number"] for t in stored}),
        "errors": sum(errors.values()),
        "locked": log.count("database is locked")
        + sum(n for text, n in errors.items() if "locked" in text),
    }


def run_optuna(workdir: Path, clients: int, cycles: int) -> dict[str, float]:
    import optuna

    optuna.logging.set_verbosity(optuna.logging.ERROR)
    storage = optuna.storages.RDBStorage(f"sqlite:///{workdir / 'optuna.db'}")
    study = optuna.create_study(
        study_name="throughput", storage=storage, sampler=optuna.samplers.RandomSampler(seed=0)
    )
    errors: Counter[str] = Counter()
    told: dict[int, float] = {}
    guard = threading.Lock()

    def client(index: int) -> None:
        for i in range(cycles):
            try:
                trial = study.ask()
                trial.suggest_float("x", 0, 1)
                value = index * 1e6 + i
                study.tell(trial, value)
            except Exception as error:  # count, as the HTTP clients count non-200s
                errors[str(error)[:80]] += 1
                continue
            with guard:
                told[trial._trial_id] = value

    start = time.perf_counter()
    threads = [threading.Thread(target=client, args=(i,)) for i in range(clients)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    elapsed = time.perf_counter() - start
    stored = study.get_trials(deepcopy=False)
    stored_values = {t._trial_id: t.value for t in stored if t.value is not None}
    return {
        "cycles": len(told),
        "seconds": elapsed,
        "rate": len(told) / elapsed,
        "lost": sum(1 for k, v in told.items() if stored_values.get(k) != v),
        "duplicated": len(stored) - len({t.number for t in stored}),
        "errors": sum(errors.values()),
        "locked": sum(n for text, n in errors.items() if "locked" in text),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--clients", type=int, default=8)
    parser.add_argument("--cycles", type=int, default=150, help="ask+tell cycles per client")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as temp:
        workdir = Path(temp)
        ours = run_activedesign(workdir, args.clients, args.cycles)
        theirs = run_optuna(workdir, args.clients, args.cycles)
    print(f"{args.clients} concurrent clients, {args.cycles} ask+tell cycles each, SQLite files")
    print(f"{'':<28}{'cycles/s':>10}{'cycles':>8}{'lost':>6}{'dup':>5}{'errors':>8}{'locked':>8}")
    for label, result in (("activedesign (HTTP)", ours), ("optuna RDBStorage (local)", theirs)):
        print(
            f"{label:<28}{result['rate']:>10.1f}{result['cycles']:>8.0f}{result['lost']:>6.0f}"
            f"{result['duplicated']:>5.0f}{result['errors']:>8.0f}{result['locked']:>8.0f}"
        )
    print(f"ratio activedesign/optuna: {ours['rate'] / theirs['rate']:.1f}x (goal >= 10x)")
    emit("activedesign", ours["rate"], higher_is_better=True, unit="cycles/s")
    emit("optuna RDBStorage", theirs["rate"], higher_is_better=True, unit="cycles/s")
    emit("activedesign / optuna", ours["rate"] / theirs["rate"], higher_is_better=True)
    sys.exit(1 if ours["lost"] or ours["duplicated"] or ours["errors"] or ours["locked"] else 0)


if __name__ == "__main__":
    main()
