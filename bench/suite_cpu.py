"""Where the test suite spends its CPU, test by test: each test's CPU with that of the
processes it started (servers, workers, browsers). ``make test`` is CPU-bound on a
2-core machine, so its wall time is this total over the cores.

    python bench/suite_cpu.py [--out DIR] [--top N] [-- PYTEST_ARGS]   # from the repo root

runs pytest (by default as ``make test`` does: ``-n 3 --dist loadgroup``) with this
module as a plugin and prints the modules and tests that cost most. A test's CPU is read
from /proc when it starts and when it ends: its process's own, the children it reaped,
and each live descendant's own and reaped children's. A process reparented away from the
test process (a daemon, Chromium's helpers once the browser exits) is missed; a module's
shared fixtures count towards the test that starts or ends them.
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

OUT = "AD_SUITE_CPU_DIR"
"""The folder each test process writes its lines to (set by :func:`main`)."""
TICK = os.sysconf("SC_CLK_TCK")


def _descendants_cpu(root: int) -> float:
    """CPU seconds of ``root``'s live descendants, each with its reaped children."""
    children: dict[int, list[int]] = {}
    cpu: dict[int, int] = {}
    for name in os.listdir("/proc"):
        if not name.isdigit():
            continue
        try:
            stat = Path(f"/proc/{name}/stat").read_text()
        except OSError:  # gone meanwhile
            continue
        fields = stat[stat.rfind(")") + 2 :].split()
        children.setdefault(int(fields[1]), []).append(int(name))
        cpu[int(name)] = sum(int(value) for value in fields[11:15])  # utime stime cutime cstime
    total, stack = 0, list(children.get(root, []))
    while stack:
        pid = stack.pop()
        total += cpu.get(pid, 0)
        stack.extend(children.get(pid, []))
    return total / TICK


def _now() -> tuple[float, float]:
    """(this process's CPU, its children's: reaped and live)."""
    own = resource.getrusage(resource.RUSAGE_SELF)
    reaped = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime, (
        reaped.ru_utime + reaped.ru_stime + _descendants_cpu(os.getpid())
    )


_started: dict[str, tuple[tuple[float, float], float]] = {}


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item: pytest.Item) -> None:
    if os.environ.get(OUT):
        _started[item.nodeid] = (_now(), time.monotonic())


def pytest_runtest_logfinish(nodeid: str) -> None:
    if nodeid not in _started:
        return
    (own, kids), start = _started.pop(nodeid)
    own_now, kids_now = _now()
    line = {"id": nodeid, "own": own_now - own, "kids": kids_now - kids}
    line["wall"] = time.monotonic() - start
    with (Path(os.environ[OUT]) / f"cpu-{os.getpid()}.jsonl").open("a") as out:
        out.write(json.dumps(line) + "\n")


def report(folder: Path, top: int) -> str:
    """The modules and tests that cost most, from the lines in ``folder``."""
    rows = [json.loads(line) for path in folder.glob("cpu-*.jsonl") for line in path.open()]
    modules: collections.Counter[str] = collections.Counter()
    counts: collections.Counter[str] = collections.Counter()
    for row in rows:
        module = row["id"].split("::")[0]
        modules[module] += row["own"] + row["kids"]
        counts[module] += 1
    lines = [f"{len(rows)} tests, {sum(modules.values()):.1f} CPU-s (own and descendants)"]
    lines += [
        f"{cpu:8.1f} s {counts[name]:5d} tests  {name}" for name, cpu in modules.most_common(top)
    ]
    lines.append("tests:")
    rows.sort(key=lambda row: -(row["own"] + row["kids"]))
    for row in rows[:top]:
        cost = row["own"] + row["kids"]
        lines.append(f"{cost:8.1f} s (own {row['own']:.1f}, wall {row['wall']:.1f})  {row['id']}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, help="keep the per-test lines in this folder")
    parser.add_argument("--top", type=int, default=40, help="modules and tests to print")
    parser.add_argument("pytest_args", nargs="*", default=["-n", "3", "--dist", "loadgroup"])
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="suite-cpu-") as scratch:
        folder = args.out or Path(scratch)
        folder.mkdir(parents=True, exist_ok=True)
        command = [sys.executable, "-m", "pytest", "-q", "-p", "bench.suite_cpu"]
        done = subprocess.run([*command, *args.pytest_args], env={**os.environ, OUT: str(folder)})
        print(report(folder, args.top))
    return done.returncode


if __name__ == "__main__":
    sys.exit(main())
