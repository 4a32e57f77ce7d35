"""What a small design study's creation costs (issue 58: its representation in a child).

A real ``adserver`` on a fresh SQLite file; after one creation that warms it (imports,
the creation helper's start), ``--creations`` creations one after another of
examples/multi-structure.yaml's space (six trees of 3 to 5 links, 192 reference designs)
with the random proposer. Figures, per creation: the median wall time of its request,
the CPU of the server process, and the CPU of the server and every process under it
together (the creation's child included, counted by its helper once reaped).

    python bench/creation_cost.py [--creations 30]
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

import httpx
import yaml

from adclient.testing.figures import emit
from adclient.testing.servers import SDK_HEADERS, ServerProcess

EXAMPLE = Path(__file__).resolve().parent.parent / "examples" / "multi-structure.yaml"


def _stat(pid: int) -> list[str]:
    with open(f"/proc/{pid}/stat") as stat:
        return stat.read().rsplit(")", 1)[1].split()


def cpu_seconds(pid: int) -> tuple[float, float]:
    """(the process's own CPU, its own and every live descendant's with their reaped
    children's)."""
    parents: dict[int, int] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                parents[int(entry)] = int(_stat(int(entry))[1])
            except (OSError, IndexError, ValueError):
                continue
    tree, grown = {pid}, True
    while grown:
        below = {child for child, parent in parents.items() if parent in tree} - tree
        tree |= below
        grown = bool(below)
    tick = os.sysconf("SC_CLK_TCK")
    own = sum(int(field) for field in _stat(pid)[11:13]) / tick
    total = 0.0
    for member in tree:
        try:
            fields = _stat(member)
        except OSError:
            continue
        total += sum(int(field) for field in fields[11:15]) / tick
    return own, total


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--creations", type=int, default=30)
    args = parser.parse_args()
    body = yaml.safe_load(EXAMPLE.read_text())
    body.pop("task")
    body["proposer"] = {"name": "random"}
    with tempfile.TemporaryDirectory() as folder:
        work = Path(folder)
        server = ServerProcess(database_url=f"sqlite:///{work / 'bench.db'}", workdir=work)
        server.start()
        try:
            assert server.process is not None
            with httpx.Client(base_url=server.url, headers=SDK_HEADERS, verify=False) as http:
                http.post("/api/v1/studies", json=body, timeout=120).raise_for_status()
                own0, total0 = cpu_seconds(server.process.pid)
                walls = []
                for _ in range(args.creations):
                    started = time.perf_counter()
                    http.post("/api/v1/studies", json=body, timeout=120).raise_for_status()
                    walls.append(time.perf_counter() - started)
                own1, total1 = cpu_seconds(server.process.pid)
        finally:
            server.stop()
    count = args.creations
    emit("creation wall", statistics.median(walls) * 1e3, higher_is_better=False, unit="ms")
    emit("server CPU", (own1 - own0) / count * 1e3, higher_is_better=False, unit="ms")
    emit("all CPU", (total1 - total0) / count * 1e3, higher_is_better=False, unit="ms")


if __name__ == "__main__":
    main()
