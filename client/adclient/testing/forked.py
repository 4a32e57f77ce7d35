"""``adserver`` runs forked from a process that has already imported it.

An ``adserver`` process spends about 1.8 of its 2.5 s of start-up CPU importing
FastAPI, SQLAlchemy, pydantic, Alembic and the service; a test run starts hundreds. Here a
``multiprocessing`` fork server imports those modules once (``PRELOAD``, by name), and
each server is a fresh process forked from it that runs the installed ``adserver``
program's entry point (found with ``importlib.metadata``, as its console script finds
it) with its own arguments, environment, working folder and log: the same program,
without paying for its imports again. The SDK still never imports the service: this
module only names the program and the modules to preload. A process whose
``PYTHONPATH`` differs from this one's (a plugin folder), or any run when
``AD_TESTING_EXEC=1``, is started by command instead (:func:`can_fork`).
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import signal
import subprocess
import sys
from collections.abc import Mapping
from functools import cache
from importlib.metadata import EntryPoint, entry_points
from multiprocessing.context import ForkServerContext
from pathlib import Path

PRELOAD = [
    "adservice.cli",
    "adservice.app",
    "adservice.server",
    "adservice.db",
    "adclient.testing.forked",  # the forked process's body
    # What a server imports only as it starts: the migrations' machinery, the built-in
    # tasks and learners its catalogue loads, and uvicorn's loop, lifespan and protocols.
    "alembic.command",
    "alembic.config",
    "alembic.script",
    "alembic.runtime.migration",
    "adclient.builtin_tasks",
    "adclient.builtin_learners",
    "sqlite3",
    "tomllib",
    "encodings.idna",
    "anyio._backends._asyncio",
    "anyio.streams.memory",
    "typer._adapters",
    "typer._click.decorators",
    "fastapi.telemetry._runtime",
    "uvicorn.lifespan.on",
    "uvicorn.loops.auto",
    "uvicorn.loops.uvloop",
    "uvicorn.protocols.websockets.auto",
]
"""What the fork server imports once: every module an ``adserver`` imports to start and
answer, so that a forked one imports nothing (tests/client/test_testing_forked.py). A
name that does not import here (uvloop not installed) is skipped by the fork server."""


@cache
def _program() -> EntryPoint | None:
    """The installed ``adserver`` console script's entry point."""
    found = entry_points(group="console_scripts", name="adserver")
    return next(iter(found), None)


def can_fork(env: Mapping[str, str]) -> bool:
    """Whether a program with ``env`` may be forked: it must see the modules this process
    sees (its ``PYTHONPATH`` is this one's), and the environment has not asked for real
    executions (``AD_TESTING_EXEC=1``)."""
    if env.get("AD_TESTING_EXEC") == "1" or os.environ.get("AD_TESTING_EXEC") == "1":
        return False
    if _program() is None or _BROKEN:
        return False
    return env.get("PYTHONPATH", "") == os.environ.get("PYTHONPATH", "")


_BROKEN: list[str] = []
"""Why the fork server could not start in this process (then every run is by command)."""


@cache
def _context() -> ForkServerContext:
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload(PRELOAD)
    return context


def _adserver(argv: list[str], env: dict[str, str], cwd: str, output: str, entry: str) -> None:
    """The forked process's body: ``adserver ARGV`` in ``cwd`` with exactly ``env``, its
    output appended to ``output``; ``entry`` is the console script's entry point (found
    by the parent: looking it up scans every installed distribution's metadata)."""
    os.environ.clear()
    os.environ.update(env)
    os.chdir(cwd)
    fd = os.open(output, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
    os.dup2(fd, 1)
    os.dup2(fd, 2)
    os.close(fd)
    sys.argv = ["adserver", *argv]
    EntryPoint("adserver", entry, "console_scripts").load()()  # preloaded: no import cost


class ForkUnavailable(RuntimeError):
    """The fork server could not start here; start the program by command."""


class ForkedProcess:
    """The part of :class:`subprocess.Popen` the harness uses, for a forked program."""

    def __init__(self, argv: list[str], *, env: Mapping[str, str], cwd: Path, output: Path):
        program = _program()
        assert program is not None  # can_fork checked it
        self._process = _context().Process(
            target=_adserver,
            args=(argv, dict(env), str(cwd), str(output), program.value),
            daemon=False,
        )
        try:
            self._process.start()
        except OSError as exc:  # the fork server's socket (e.g. a TMPDIR past 107 characters)
            _BROKEN.append(str(exc))
            raise ForkUnavailable(str(exc)) from exc
        assert self._process.pid is not None  # started
        self.pid: int = self._process.pid
        self.args = ["adserver", *argv]

    @property
    def returncode(self) -> int | None:
        return self._process.exitcode

    def poll(self) -> int | None:
        return self._process.exitcode

    def wait(self, timeout: float | None = None) -> int:
        self._process.join(timeout)
        if self._process.exitcode is None:
            raise subprocess.TimeoutExpired(self.args, timeout or 0.0)
        return self._process.exitcode

    def send_signal(self, signum: int) -> None:
        if self._process.exitcode is None:
            os.kill(self.pid, signum)

    def terminate(self) -> None:
        self.send_signal(signal.SIGTERM)

    def kill(self) -> None:
        self.send_signal(signal.SIGKILL)


def run_adserver(argv: list[str], *, env: Mapping[str, str], cwd: Path, output: Path) -> int:
    """Run ``adserver ARGV`` to its end (a forked one where :func:`can_fork`); its output
    is appended to ``output``; returns its exit status."""
    if can_fork(env):
        with contextlib.suppress(ForkUnavailable):
            return ForkedProcess(argv, env=env, cwd=cwd, output=output).wait()
    adserver = Path(sys.executable).with_name("adserver")
    with output.open("ab") as log:
        done = subprocess.run(
            [str(adserver), *argv], env=dict(env), cwd=cwd, stdout=log, stderr=subprocess.STDOUT
        )
    return done.returncode
