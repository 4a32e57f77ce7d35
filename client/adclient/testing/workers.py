"""Real ``adworker`` and ``adclient`` processes, an offline ``pip install`` of a plugin, and
a bounded wait."""

from __future__ import annotations

import contextlib
import math
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from adclient.testing.forked import ForkedProcess, ForkUnavailable, can_fork
from adclient.testing.servers import ServerProcess

ADWORKER = Path(sys.executable).with_name("adworker")
ADCLIENT = Path(sys.executable).with_name("adclient")
PATIENCE = 300.0
"""A bound on waits so a broken build fails instead of hanging; not a speed check."""
STOP_GRACE = 5.0
"""Seconds a stopped worker gets after each of its two SIGTERMs (finish the job, then
abandon it) to exit on its own before it is killed."""


def pip_install_target(source: Path, work: Path) -> Path:
    """A package folder as ``pip install`` leaves it (the package and its dist-info with
    its entry points), in ``work/site``, a folder that only the processes given it on
    their PYTHONPATH see. Built from a copy (the build writes files), offline, without
    its dependencies: what it needs must be in the venv already."""
    copy = shutil.copytree(source, work / "source", ignore=shutil.ignore_patterns("__pycache__"))
    site = work / "site"
    offline = ["--quiet", "--no-deps", "--no-index", "--no-build-isolation"]
    subprocess.run(
        [sys.executable, "-m", "pip", "install", *offline, "--target", str(site), str(copy)],
        check=True,
    )
    return site


def plugin_path(site: Path) -> dict[str, str]:
    """The environment of a process that sees the package installed in ``site``: it first
    on the PYTHONPATH, then what this process has there (a worktree's code)."""
    return {"PYTHONPATH": os.pathsep.join(filter(None, [str(site), os.getenv("PYTHONPATH")]))}


class WorkerProcess:
    """One ``adworker`` process with its log file; ``env`` adds to the environment. It is
    forked from preloaded imports where it can be (:mod:`.forked`; not with ``--ray``,
    whose processes Ray starts), else started by command."""

    def __init__(
        self,
        server: ServerProcess,
        workdir: Path,
        worker_id: str,
        *args: str,
        env: dict[str, str] | None = None,
    ) -> None:
        self.worker_id = worker_id
        self.log_path = workdir / f"{worker_id}.log"
        environment = {**os.environ, "AD_SERVER_URL": server.url, **(env or {})}
        environment.pop("AD_TOKEN", None)
        argv = ["--worker-id", worker_id, "--poll", "0.2", *args]
        process: subprocess.Popen[bytes] | ForkedProcess | None = None
        ray = "--ray" in args or "AD_RAY_ADDRESS" in environment
        if not ray and can_fork(environment, "adworker"):
            with contextlib.suppress(ForkUnavailable):
                process = ForkedProcess(
                    argv, env=environment, cwd=Path.cwd(), output=self.log_path, program="adworker"
                )
        if process is None:
            with self.log_path.open("ab") as log:
                process = subprocess.Popen(
                    [str(ADWORKER), *argv], env=environment, stdout=log, stderr=subprocess.STDOUT
                )
        self.process = process

    def log(self) -> str:
        return self.log_path.read_text(errors="replace")

    def wait(self, timeout: float = PATIENCE) -> int:
        return self.process.wait(timeout=timeout)

    def signal(self, signum: int) -> None:
        self.process.send_signal(signum)

    def stop(self) -> None:
        """Stop the worker as a user does (``stop_workers``)."""
        stop_workers([self])


def stop_workers(workers: list[WorkerProcess]) -> None:
    """Stop workers as a user does, so each gives its job back and removes its temporary
    folder: SIGTERM to all, a second one to those still busy after ``STOP_GRACE``,
    SIGKILL only to those that does not end either (a killed worker's folder stays until
    the next worker on the machine starts). All at once, so a study's workers take one
    grace, not one each."""
    for signum in (signal.SIGTERM, signal.SIGTERM, signal.SIGKILL):
        running = [worker for worker in workers if worker.process.poll() is None]
        for worker in running:
            worker.process.send_signal(signum)
        ends = time.monotonic() + STOP_GRACE
        for worker in running:
            with contextlib.suppress(subprocess.TimeoutExpired):
                worker.process.wait(timeout=max(0.0, ends - time.monotonic()))
    for worker in workers:
        worker.process.wait()  # reaped: every one has ended by now, SIGKILL at the latest


def wait_for(condition: Callable[[], object], what: str, poll: float = 0.25) -> object:
    """``condition()``'s first true value: checked at once, then after each of
    :func:`pauses` (``poll`` at most); an AssertionError naming ``what`` after
    ``PATIENCE`` seconds."""
    deadline = time.monotonic() + PATIENCE
    for pause in pauses(poll):
        value = condition()
        if value:
            return value
        if time.monotonic() >= deadline:
            break
        time.sleep(pause)
    raise AssertionError(f"gave up waiting for {what}")


def pauses(poll: float) -> Iterator[float]:
    """A wait's pauses between checks: from 0.05 s, half as long again each time, up to
    ``poll``. What shows at once is seen soon, and a longer wait checks 4 times a second
    (0.25), not 20: a check that asks the server costs it CPU each time (the trials of a
    study, 5 ms), and what a test waits to catch lasts seconds."""
    pause = min(0.05, poll)
    while True:
        yield pause
        pause = min(poll, pause * 1.5)


def completed_trials(study: Any, count: int) -> list[Any]:
    """Wait for a managed study (an ``adclient`` StudyHandle) to finish; its complete
    trials, of which there must be ``count``, each with a finite value."""
    final = study.wait(poll=0.2, timeout=PATIENCE)
    assert final.n_complete == count, [trial.message for trial in study.trials]
    complete = [trial for trial in study.trials if trial.state == "complete"]
    assert all(math.isfinite(trial.value) for trial in complete)
    return complete


def run_adclient(server: ServerProcess, *args: str) -> subprocess.CompletedProcess[str]:
    """The ``adclient`` CLI as a user runs it against ``server``: plain text, wide (forked
    from preloaded imports where it can be, :mod:`.forked`)."""
    environment = {**os.environ, "AD_SERVER_URL": server.url, "NO_COLOR": "1", "COLUMNS": "200"}
    environment.pop("AD_TOKEN", None)
    return _run(ADCLIENT, list(args), environment)


def run_adworker(*args: str, **env: str) -> subprocess.CompletedProcess[str]:
    """``adworker ARGS`` run to its end (one that stops at start), ``env`` added to the
    environment, its output read back (forked from preloaded imports where it can be:
    one that checks a GPU would import torch first)."""
    return _run(ADWORKER, list(args), {**os.environ, **env})


def _run(command: Path, argv: list[str], env: dict[str, str]) -> subprocess.CompletedProcess[str]:
    """``COMMAND ARGV`` to its end as ``subprocess.run`` with ``capture_output`` and
    ``text`` runs it, forked where it can be."""
    if can_fork(env, command.name):
        with contextlib.suppress(ForkUnavailable):
            return _forked(command, argv, env)
    return subprocess.run(
        [str(command), *argv], env=env, capture_output=True, text=True, timeout=PATIENCE
    )


def _forked(
    command: Path, argv: list[str], env: dict[str, str]
) -> subprocess.CompletedProcess[str]:
    """``COMMAND ARGV`` forked, its stdout and stderr read back as ``subprocess.run``
    with ``capture_output`` and ``text`` reads them."""
    with tempfile.TemporaryDirectory(prefix=f"{command.name}-") as folder:
        out, err = Path(folder, "stdout"), Path(folder, "stderr")
        process = ForkedProcess(
            argv, env=env, cwd=Path.cwd(), output=out, errors=err, program=command.name
        )
        try:
            code = process.wait(timeout=PATIENCE)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
            raise
        read = [path.read_text() if path.exists() else "" for path in (out, err)]
    return subprocess.CompletedProcess([str(command), *argv], code, *read)
