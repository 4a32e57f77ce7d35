"""What a worker's job costs beyond its own work: the round trip of each job to the
worker's job process (adworker.jobprocess) and back, on short jobs, where it shows most.

A real ``adserver`` and real ``adworker`` processes (started by command, so the CPU time
of a worker and of the job process it started is read back with ``os.wait4``): one
worker runs 1 job, another ``1 + --jobs`` jobs of the same study (stand-up, the
``fast`` learner at 64 steps, one evaluation episode, no picture: about 0.1 s a job);
the difference is what ``--jobs`` jobs cost, without the worker's start. Reported per
job: the worker's wall time and CPU time (its processes together).

Run: ``.venv/bin/python bench/job_process.py [--jobs 40]``; as a comparison:
``.venv/bin/python bench/compare.py --baseline COMMIT -- bench/job_process.py``.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import tempfile
import time
from pathlib import Path

import yaml

from adclient import Client
from adclient.testing.figures import emit
from adclient.testing.servers import ServerProcess
from adclient.testing.workers import ADWORKER

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def run_worker(server: ServerProcess, work: Path, name: str, jobs: int) -> tuple[float, float]:
    """A worker's wall and CPU seconds (its process and the job process it waited for)
    for ``jobs`` jobs, start included."""
    env = {**os.environ, "AD_SERVER_URL": server.url, "OMP_NUM_THREADS": "1"}
    env.pop("AD_TOKEN", None)
    argv = [str(ADWORKER), "--worker-id", name, "--max-jobs", str(jobs), "--no-render"]
    started = time.perf_counter()
    with (work / f"{name}.log").open("wb") as log:
        process = subprocess.Popen(argv, env=env, stdout=log, stderr=subprocess.STDOUT)
        _, status, usage = os.wait4(process.pid, 0)
    process.returncode = os.waitstatus_to_exitcode(status)
    if process.returncode != 0:
        raise SystemExit(
            f"adworker exited {process.returncode}: {(work / f'{name}.log').read_text()}"
        )
    return time.perf_counter() - started, usage.ru_utime + usage.ru_stime


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--jobs", type=int, default=40)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="job-process-") as folder:
        work = Path(folder)
        server = ServerProcess(database_url=f"sqlite:///{work / 'ad.db'}", workdir=work).start()
        try:
            body = yaml.safe_load((EXAMPLES / "stand-up.yaml").read_text())
            body["max_trials"] = args.jobs + 2
            body["proposer"] = {"name": "random", "seed": 0}
            body["task"].update({"learner": "fast", "train_steps": 64, "eval_episodes": 1})
            with Client(server.url) as client:
                study = client.create_study(body)
                one_wall, one_cpu = run_worker(server, work, "one", 1)
                many_wall, many_cpu = run_worker(server, work, "many", 1 + args.jobs)
                done = client.study_info(study.id)
            if done.n_complete != args.jobs + 2:
                raise SystemExit(f"{done.n_complete} of {args.jobs + 2} jobs complete")
        finally:
            server.stop()
    emit("wall per job", (many_wall - one_wall) / args.jobs, higher_is_better=False, unit="s")
    emit("worker CPU per job", (many_cpu - one_cpu) / args.jobs, higher_is_better=False, unit="s")


if __name__ == "__main__":
    main()
