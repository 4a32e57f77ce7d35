"""``adserver`` and ``adworker`` run forked from a process that has already imported them.

An ``adserver`` process spends about 1.8 of its 2.5 s of start-up CPU importing
FastAPI, SQLAlchemy, pydantic, Alembic and the service, an ``adworker`` about 3.5 s importing
torch, stable-baselines3 and PyBullet (and 1.7 s more at its first stable-baselines3 job:
torch's compiler); a test run starts hundreds. Here a
``multiprocessing`` fork server per program imports its modules once (``PRELOAD``, by
name), and each process is a fresh one forked from it that runs the installed program's
entry point (found with ``importlib.metadata``, as its console script finds it) with its
own arguments, environment, working folder and log: the same program, without paying
for its imports again. The SDK still never imports the service or the worker: this
module only names the programs and the modules to preload. Each program has a fork
server of its own: a server forked from one holding the worker's imports too carries
them (a full garbage collection in it took 258 ms of CPU against 145), and every forked
process freezes the objects it inherits, which its collections then skip.

The forked process starts as an exec'd one would: ``os.environ`` is its own, what the
preloaded modules computed from the fork server's environment is recomputed (the
temporary folder, ``functools.cache`` values of the project's modules, the root
logger's handlers), ``sys.path`` is the command's, the signal handlers are the
defaults, its ``atexit`` functions run, an uncaught exception is printed and is exit
status 1 (a ``KeyboardInterrupt`` ends it by SIGINT), and ``sys.exit`` sets its status.
A process whose ``PYTHONPATH`` puts a plugin's folder before this one's is forked too,
with the exec'd one's ``sys.path``, where nothing in that folder has a name this process
finds. Any other ``PYTHONPATH``, or any run when ``AD_TESTING_EXEC=1``, is started by
command instead (:func:`can_fork`), as is anything the caller knows cannot be faithful
(``adworker --ray``: Ray's own processes).
"""

from __future__ import annotations

import atexit
import contextlib
import gc
import importlib.util
import io
import logging
import os
import signal
import subprocess
import sys
import tempfile
from collections.abc import Mapping
from functools import cache
from importlib.metadata import EntryPoint, PackageNotFoundError, distribution, entry_points
from multiprocessing import forkserver, popen_forkserver, reduction, spawn, util
from multiprocessing.context import ForkServerProcess, set_spawning_popen
from pathlib import Path
from typing import Any

PRELOAD = {
    "adserver": (
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
        # What its first model-based proposal imports, about 2.6 s of CPU a server: the
        # third-party libraries only (the project's proposer modules read the server's
        # settings as they are imported, so each forked server imports those itself).
        "torch",
        "botorch",
        "botorch.models",
        "botorch.optim.utils",
        "botorch.acquisition.multi_objective.logei",
        "gpytorch",
        "scipy.optimize",
        "threadpoolctl",
    ),
    "adworker": (
        "adworker.cli",
        "adworker.pool",
        "adworker.evaluate",
        "adworker.functions",
        "adworker.tasks",
        "stable_baselines3",
        "torch",
        "torch._dynamo",  # torch.optim imports it at a learner's first optimizer: 1.7 s
        "pybullet",
        "adworker.tasks.mujoco_engine",  # mujoco, for a study's task.simulator: mujoco
    ),
    "adclient": ("adclient.cli",),
}
"""What each program's fork server imports once: what the program imports to start and
(``adworker``) to run its first job; for ``adserver``, every module it imports to start
and answer, so that a forked one imports nothing (tests/client/test_testing_forked.py),
and the libraries of its first model-based proposal. A name that does not import here
(uvloop not installed) is skipped by the fork server.
Importing them starts no thread pool (torch's start at their first use)."""

PROJECT_PACKAGES = ("adclient", "adservice", "adworker")
"""The packages whose module-level ``functools.cache`` values a forked process drops."""


@cache
def _program(name: str) -> EntryPoint | None:
    """The installed console script ``name``'s entry point."""
    found = entry_points(group="console_scripts", name=name)
    return next(iter(found), None)


def can_fork(env: Mapping[str, str], program: str = "adserver") -> bool:
    """Whether ``program`` with ``env`` may be forked: it must find the modules an
    exec'd one would (:func:`_added_folders`), and the environment has not asked for
    real executions (``AD_TESTING_EXEC=1``)."""
    if env.get("AD_TESTING_EXEC") == "1" or os.environ.get("AD_TESTING_EXEC") == "1":
        return False
    if _program(program) is None or _BROKEN:
        return False
    return _added_folders(env.get("PYTHONPATH", "")) is not None


METADATA = (".dist-info", ".egg-info")


@cache
def _added_folders(pythonpath: str) -> tuple[str, ...] | None:
    """The folders ``pythonpath`` puts before this process's ``PYTHONPATH`` (a plugin
    installed in a folder of its own), or None when a process with it cannot be forked:
    it is not those folders then this one's, or one of them holds a module or a
    distribution's metadata of a name this process finds, which the fork server has
    (or may have) imported or read from elsewhere. Modules and distributions of new
    names are found where the exec'd process finds them: the forked one's ``sys.path``
    is the exec'd one's, and a plugin's are imported and read after the fork."""
    own = os.environ.get("PYTHONPATH", "")
    if pythonpath == own:
        return ()
    head = pythonpath.removesuffix(os.pathsep + own) if own else pythonpath
    if head == pythonpath and own:
        return None
    folders = tuple(folder for folder in head.split(os.pathsep) if folder)
    for folder in folders:
        for entry in Path(folder).iterdir() if Path(folder).is_dir() else ():
            name, suffix = os.path.splitext(entry.name)
            if suffix in METADATA:
                with contextlib.suppress(PackageNotFoundError):
                    distribution(name.split("-")[0])
                    return None
            elif entry.name != "__pycache__" and importlib.util.find_spec(entry.name.split(".")[0]):
                return None
    return folders


_BROKEN: list[str] = []
"""Why a fork server could not start in this process (then every run is by command)."""


@cache
def _exec_path(pythonpath: str) -> list[str]:
    """The ``sys.path`` a program started by command with ``pythonpath`` has: its
    script's folder (this interpreter's), then what a fresh interpreter with this
    environment and that ``PYTHONPATH`` finds; the fork servers have this process's, to
    which pytest adds its own folders."""
    fresh = "import sys; print(*sys.path[1:], sep=chr(10))"
    env = {**os.environ, "PYTHONPATH": pythonpath}
    done = subprocess.run(
        [sys.executable, "-c", fresh], capture_output=True, text=True, check=True, env=env
    )
    return [str(Path(sys.executable).parent), *done.stdout.splitlines()]


@cache
def _server(program: str) -> forkserver.ForkServer:
    """``program``'s fork server (started at its first process)."""
    server = forkserver.ForkServer()
    server.set_forkserver_preload(list(PRELOAD[program]))
    return server


class _Popen(popen_forkserver.Popen):
    """multiprocessing's fork-server launch, through the fork server of the program the
    process runs rather than the one global fork server."""

    def _launch(self, process_obj: Any) -> None:  # popen_forkserver.Popen._launch's steps
        prep_data = spawn.get_preparation_data(process_obj._name)
        buf = io.BytesIO()
        set_spawning_popen(self)
        try:
            reduction.dump(prep_data, buf)
            reduction.dump(process_obj, buf)
        finally:
            set_spawning_popen(None)
        server = _server(process_obj._args[0])
        self.sentinel, w = server.connect_to_new_process(self._fds)  # type: ignore[attr-defined]
        parent_w = os.dup(w)  # the child's sentinel of this process, as the stdlib keeps it
        close_fds = util.close_fds  # type: ignore[attr-defined]
        self.finalizer = util.Finalize(self, close_fds, (parent_w, self.sentinel))
        with open(w, "wb", closefd=True) as f:
            f.write(buf.getbuffer())
        self.pid = forkserver.read_signed(self.sentinel)


class _ProgramProcess(ForkServerProcess):
    @staticmethod
    def _Popen(process_obj: Any) -> _Popen:
        return _Popen(process_obj)


def _fresh_start() -> None:
    """Drop what the preloaded modules computed from the fork server's environment, and
    freeze the objects the preloading made (``gc.freeze``: the child's collections skip
    them instead of reading, and so copying, the fork server's pages: a full collection
    in a child of the worker's preloads took 240 ms of CPU, 12 ms frozen)."""
    gc.freeze()
    tempfile.tempdir = None
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    for handler in logging.root.handlers[:]:
        logging.root.removeHandler(handler)
    for name, module in list(sys.modules.items()):
        if module is None or name.split(".")[0] not in PROJECT_PACKAGES:
            continue
        for value in list(vars(module).values()):
            if callable(getattr(value, "cache_clear", None)) and (
                getattr(value, "__module__", None) == name
            ):
                value.cache_clear()


def _run(
    program: str,
    argv: list[str],
    env: dict[str, str],
    cwd: str,
    outputs: list[str],
    path: list[str],
    entry: str,
) -> None:
    """The forked process's body: ``PROGRAM ARGV`` in ``cwd`` with exactly ``env``, its
    stdout and stderr appended to the two ``outputs`` (one file twice: both to it),
    ``path`` its ``sys.path``, ended as the exec'd program ends; ``entry`` is the console
    script's entry point (found by the parent: looking it up scans every installed
    distribution's metadata)."""
    os.environ.clear()
    os.environ.update(env)
    os.chdir(cwd)
    for stream, output in enumerate(outputs, start=1):
        fd = os.open(output, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
        os.dup2(fd, stream)
        os.close(fd)
    _fresh_start()
    sys.path[:] = path
    sys.argv = [program, *argv]
    code: object = 0
    interrupted = False
    try:
        EntryPoint(program, entry, "console_scripts").load()()  # preloaded: no import cost
    except SystemExit as exit_:
        code = exit_.code
    except KeyboardInterrupt:
        sys.excepthook(*sys.exc_info())
        interrupted = True
    except BaseException:
        sys.excepthook(*sys.exc_info())
        code = 1
    if code is not None and not isinstance(code, int):
        print(code, file=sys.stderr)
        code = 1
    atexit._run_exitfuncs()
    if interrupted:  # as Python ends on an uncaught KeyboardInterrupt: by the signal
        sys.stdout.flush()
        sys.stderr.flush()
        signal.signal(signal.SIGINT, signal.SIG_DFL)
        os.kill(os.getpid(), signal.SIGINT)
    raise SystemExit(code)


class ForkUnavailable(RuntimeError):
    """The fork server could not start here; start the program by command."""


class ForkedProcess:
    """The part of :class:`subprocess.Popen` the harness uses, for a forked program."""

    def __init__(
        self,
        argv: list[str],
        *,
        env: Mapping[str, str],
        cwd: Path,
        output: Path,
        program: str = "adserver",
        errors: Path | None = None,
    ):
        """``PROGRAM ARGV``, its stdout and stderr appended to ``output`` (stderr to
        ``errors`` where given)."""
        outputs = [str(output), str(errors or output)]
        path = _exec_path(env.get("PYTHONPATH", ""))
        entry = _program(program)
        assert entry is not None  # can_fork checked it
        self._process = _ProgramProcess(
            target=_run,
            args=(program, argv, dict(env), str(cwd), outputs, path, entry.value),
            daemon=False,
        )
        try:
            self._process.start()
        except OSError as exc:  # the fork server's socket (e.g. a TMPDIR past 107 characters)
            _BROKEN.append(str(exc))
            raise ForkUnavailable(str(exc)) from exc
        assert self._process.pid is not None  # started
        self.pid: int = self._process.pid
        self.args = [program, *argv]

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
