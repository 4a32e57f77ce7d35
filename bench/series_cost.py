"""What reading a wide study costs the server: 6,400 trials of 256 params (issue 13).

Starts a real ``adserver`` on a SQLite file, writes the trials straight into it, then
reads each path given (default: both series endpoints) to the end, following ``next``
where the answer has one, and prints requests, bytes, the server's CPU (all requests and
the worst one) and its peak resident memory before and after, from /proc.

    python bench/series_cost.py
    python bench/series_cost.py "/api/v1/studies/1/trials?limit=1000"
    N=1000 P=8 python bench/series_cost.py
"""

from __future__ import annotations

import os
import random
import sys
import tempfile
import time
from pathlib import Path

import httpx
import sqlalchemy as sa

from adclient.testing.servers import ServerProcess
from adservice.models import TrialRow

N, P = int(os.environ.get("N", 6400)), int(os.environ.get("P", 256))


def main(paths: list[str]) -> None:
    work = Path(tempfile.mkdtemp())
    url = f"sqlite:///{work / 'studies.db'}"
    server = ServerProcess(database_url=url, workdir=work).start()
    assert server.process is not None
    pid = server.process.pid

    def cpu() -> float:
        fields = Path(f"/proc/{pid}/stat").read_text().split(")")[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")

    def peak_mb() -> float:
        line = next(
            x for x in Path(f"/proc/{pid}/status").read_text().splitlines() if x.startswith("VmHWM")
        )
        return int(line.split()[1]) / 1024

    try:
        http = httpx.Client(base_url=server.url, timeout=600)
        space = {
            "type": "box",
            "params": [{"name": f"p{i}", "low": 0, "high": 1} for i in range(P)],
        }
        body = {"name": "wide", "space": space, "proposer": {"name": "random"}}
        study = http.post("/api/v1/studies", json=body).json()
        rng = random.Random(0)
        rows = []
        for number in range(N):
            vector = [rng.random() for _ in range(P)]
            params = {f"p{i}": v for i, v in enumerate(vector)}
            rows.append(
                {
                    "study_id": study["id"],
                    "number": number,
                    "state": "complete",
                    "vector": vector,
                    "params": params,
                    "value": rng.random(),
                    "metrics": {},
                    "info": {},
                    "attempts": 1,
                }
            )
        engine = sa.create_engine(url)
        with engine.begin() as connection:
            connection.execute(sa.insert(TrialRow), rows)
        engine.dispose()
        for path in paths or [
            f"/api/v1/studies/{study['id']}/series",
            f"/api/v1/dashboard/studies/{study['id']}/series",
        ]:
            requests = size = trials = 0
            worst = 0.0
            before_cpu, before_peak, started = cpu(), peak_mb(), time.perf_counter()
            following: str | None = path
            while following is not None:
                request_cpu = cpu()
                response = http.get(following)
                response.raise_for_status()
                worst = max(worst, cpu() - request_cpu)
                answer = response.json()
                requests, size = requests + 1, size + len(response.content)
                trials += len(answer["number"]) if isinstance(answer, dict) else len(answer)
                after = answer.get("next") if isinstance(answer, dict) else None
                following = None if after is None else f"{path.split('?')[0]}?after={after}"
            print(
                f"{path}: {requests} request(s), {trials} trials, {size / 1e6:.1f} MB, "
                f"{time.perf_counter() - started:.2f} s wall, {cpu() - before_cpu:.2f} s server "
                f"CPU (worst request {worst:.2f} s), "
                f"peak RSS {before_peak:.0f} -> {peak_mb():.0f} MB"
            )
    finally:
        server.stop()


if __name__ == "__main__":
    main(sys.argv[1:])
