"""Where a study creation's heavy checks run: child processes with budgets, a bounded queue.

Issue 58: creating a design study computed its representation (the structures'
similarity, the fusion, MDS) on AnyIO's request threads: one creation of 200 random
32-link trees took 198 s of CPU, 41 of them held every thread and the GIL, ``/healthz``
stopped answering, the work went on after its client left, and SIGTERM could not end
it. Now that work runs in a child process, at the lowest CPU priority, under limits of
its own, through a pool of places like :class:`adservice.expansions.ExpansionPool`:
``AD_CREATE_PROCESSES`` children compute at once (default 2), ``AD_CREATE_QUEUE``
creations wait (default 16), and a creation that finds every place taken is answered
503 with Retry-After before anything is stored. A child is killed when its request's
client disconnects, when it has run ``AD_CREATE_SECONDS`` (a 422 naming the setting;
its CPU time is held to that too), and when the server shuts down; it may map
``AD_CREATE_MEMORY_MB`` beyond what it started with. Waiting holds no thread.

The children are forked from a *helper*, a process the pool starts once with the
server: forked from the server while the server runs one Python thread (so the helper
and every child start with what the server imported), otherwise (an app started
inside a process that runs other threads) a fresh interpreter. At its first job the
helper imports the checks' modules and runs them once on a tiny space; a child's start
is then a fork of a warm process: about 4 ms of wall time and 0.4 ms of the server's
CPU for a job that does nothing, about 20 ms of CPU more than the same checks in the
server for a small space (130 ms). The helper only ever forks, kills and reaps. It
ends when the server does (its control socket closes), killing its children; a child
ends with the helper (``PR_SET_PDEATHSIG``), and its CPU limit ends it regardless.

A job's work is a module-level function called with picklable arguments; it returns
a JSON value (the server reads nothing but JSON from a child) or raises
:class:`~adservice.errors.InvalidError`, which is raised again in the server.
"""

from __future__ import annotations

import asyncio
import contextlib
import ctypes
import gc
import json
import logging
import os
import pickle
import resource
import select
import signal
import socket
import struct
import subprocess
import sys
import threading
import traceback
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from functools import partial
from typing import Any

from adservice.errors import BusyError, ClientGoneError, InvalidError
from adservice.fairness import OwnerShares, running_share

log = logging.getLogger(__name__)

RETRY_AFTER_SECONDS = 5
"""What a refused creation is told to wait (the SDK's longest backoff)."""
POLL_SECONDS = 0.25
"""How often a waiting or computing creation asks whether its client is still there."""
NICE = 19
"""A child's CPU priority: the lowest, so the server's requests come first."""

_RUN = 1
_KILL = 2
_CONTROL = struct.Struct("!BQdq")
"""A message to the helper: what (run, kill), the job, its seconds and its memory
(bytes beyond the child's start; -1 for none)."""
_LENGTH = struct.Struct("!Q")


@dataclass(frozen=True)
class CreationBudget:
    """What one creation's child may spend: seconds (of its life, and of CPU) and bytes of
    memory beyond what it started with (None: no limit)."""

    seconds: float
    memory_bytes: int | None


class CreationPool:
    """``processes`` children at a time, ``queue`` more creations waiting, no more."""

    def __init__(
        self,
        processes: int = 2,
        queue: int = 16,
        *,
        budget: CreationBudget,
        warm_up: Callable[[], None] | None = None,
        per_owner: int | None = None,
    ) -> None:
        """``warm_up``: a module-level function the helper runs before its first fork (the
        checks once, on a tiny space), so that each child starts with what it loaded.
        ``per_owner``: the places one owner may hold (default: all of them)."""
        self.processes = processes
        self.places = processes + queue
        self.shares = OwnerShares(
            places=per_owner or self.places,
            running=running_share(processes),
            what="study creations",
            setting="AD_CREATE_PER_OWNER",
        )
        self.budget = budget
        self.warm_up = warm_up
        self._taken = 0
        self.running = 0
        """Creations computing in a child now (the rest of the places taken wait)."""
        self._turns: asyncio.Semaphore | None = None
        self._helper: _Helper | None = None
        self._jobs = 0

    def start(self) -> None:
        """Start the helper: call it first thing at the server's start, while the server
        is still one thread (then the helper is a fork of it)."""
        self._helper = _Helper.start(self.warm_up)

    async def run(
        self,
        work: Callable[..., Any],
        *args: Any,
        disconnected: Callable[[], Awaitable[bool]] | None = None,
        owner: int | None = None,
    ) -> Any:
        """``work(*args)`` in a child, once a place is free and its ``owner``'s turn has
        come (``OwnerShares``; None: not counted): its JSON answer, or the InvalidError
        it raised. BusyError (503) at once when every place is taken, RateLimitedError
        (429) when the owner holds its share;
        InvalidError naming ``AD_CREATE_SECONDS`` or ``AD_CREATE_MEMORY_MB`` past the
        budget; ClientGoneError when ``disconnected()`` turns true meanwhile (the child
        is killed). Cancelling the call kills the child too."""
        if self._taken >= self.places:
            raise BusyError(
                f"the server is busy checking new studies ({self.processes} running and "
                f"{self.places - self.processes} waiting: AD_CREATE_PROCESSES, "
                f"AD_CREATE_QUEUE): nothing was stored; retry in {RETRY_AFTER_SECONDS} s",
                retry_after=RETRY_AFTER_SECONDS,
            )
        self.shares.take_place(owner)
        self._taken += 1
        try:
            payload = pickle.dumps((work, args), protocol=pickle.HIGHEST_PROTOCOL)
            shares = self.shares
            await _take_turn(
                partial(shares.take_turn, owner), partial(shares.give_turn, owner), disconnected
            )
            try:
                turns = self._semaphore()
                await _take_turn(turns.acquire, turns.release, disconnected)
                self.running += 1
                try:
                    answer = await self._compute(payload, disconnected)
                finally:
                    self.running -= 1
                    turns.release()
            finally:
                self.shares.give_turn(owner)
        finally:
            self._taken -= 1
            self.shares.give_place(owner)
        return _answer_of(answer, self.budget)

    def counts(self) -> tuple[int, int]:
        """(running, waiting): the places taken now (``activedesign_pool_places``)."""
        return self.running, self._taken - self.running

    def _semaphore(self) -> asyncio.Semaphore:
        if self._turns is None:  # made on the event loop that uses it
            self._turns = asyncio.Semaphore(self.processes)
        return self._turns

    async def _compute(
        self, payload: bytes, disconnected: Callable[[], Awaitable[bool]] | None
    ) -> bytes | None:
        """Run one job: its child's answer, or None when the child ended without one."""
        if self._helper is None or not self._helper.alive():
            self._helper = _Helper.start(self.warm_up)
        self._jobs += 1
        job = self._jobs
        ours, theirs = socket.socketpair()
        try:
            try:
                self._helper.run(job, self.budget, theirs)
            except OSError:  # the helper died (killed from outside): one new helper, once
                log.warning("the creation helper ended; starting another")
                self._helper = _Helper.start(self.warm_up)
                self._helper.run(job, self.budget, theirs)
        finally:
            theirs.close()
        loop = asyncio.get_running_loop()
        ours.setblocking(False)
        reading: asyncio.Future[bytes | None] | None = None
        try:
            await loop.sock_sendall(ours, _LENGTH.pack(len(payload)) + payload)
            reading = asyncio.ensure_future(_read_to_end(loop, ours))
            if await _wait(reading, disconnected, loop.time() + self.budget.seconds):
                return reading.result()
            raise InvalidError(
                "space: checking it took longer than the limit of "
                f"{self.budget.seconds:g} s (AD_CREATE_SECONDS): nothing was stored; list "
                "fewer or smaller structures, or fewer reference designs "
                "(reference_per_structure)"
            )
        finally:
            if reading is not None:
                reading.cancel()
            self._helper.kill(job)
            ours.close()

    def shutdown(self) -> None:
        """End the helper and every child (their work is abandoned: nothing is stored)."""
        if self._helper is not None:
            self._helper.stop()
            self._helper = None


async def _wait(
    future: asyncio.Future[Any],
    disconnected: Callable[[], Awaitable[bool]] | None,
    deadline: float | None = None,
) -> bool:
    """Wait for ``future`` (not cancelling it): True once it is done, False at the loop's
    ``deadline``; ClientGoneError as soon as ``disconnected()`` turns true."""
    loop = asyncio.get_running_loop()
    while not future.done():
        timeout = POLL_SECONDS if deadline is None else min(POLL_SECONDS, deadline - loop.time())
        if timeout <= 0:
            return False
        await asyncio.wait({future}, timeout=timeout)
        if not future.done() and disconnected is not None and await disconnected():
            raise ClientGoneError(
                "the client went away: its study's checks were stopped, nothing stored"
            )
    return True


async def _take_turn(
    acquire: Callable[[], Awaitable[Any]],
    release: Callable[[], None],
    disconnected: Callable[[], Awaitable[bool]] | None,
) -> None:
    """``acquire()`` a turn, unless the client goes first or the call is cancelled (then
    a turn acquired meanwhile is given back with ``release()``)."""
    taking = asyncio.ensure_future(acquire())
    try:
        await _wait(taking, disconnected)
    except BaseException:
        if taking.done() and not taking.cancelled() and taking.exception() is None:
            release()
        else:
            taking.cancel()
        raise


async def _read_to_end(loop: asyncio.AbstractEventLoop, sock: socket.socket) -> bytes | None:
    """What the child wrote before it closed its end; None when it wrote no whole answer."""
    chunks = []
    while chunk := await loop.sock_recv(sock, 1 << 20):
        chunks.append(chunk)
    data = b"".join(chunks)
    if len(data) < _LENGTH.size:
        return None
    (length,) = _LENGTH.unpack_from(data)
    body = data[_LENGTH.size :]
    return body if len(body) == length else None


def _answer_of(answer: bytes | None, budget: CreationBudget) -> Any:
    """The work's JSON value, or its error raised again."""
    memory = (
        f"{budget.memory_bytes / 2**20:g} MB (AD_CREATE_MEMORY_MB)"
        if budget.memory_bytes is not None
        else "the memory this machine has"
    )
    if answer is None:
        raise InvalidError(
            "space: checking it ended without an answer: it needed more than its limits "
            f"({budget.seconds:g} s of CPU, AD_CREATE_SECONDS; {memory}); nothing was stored"
        )
    result = json.loads(answer)
    if "value" in result:
        return result["value"]
    if "invalid" in result:
        raise InvalidError(result["invalid"], problems=result.get("problems"))
    if "memory" in result:
        raise InvalidError(
            f"space: checking it needs more memory than the limit of {memory}: nothing was "
            "stored; list fewer or smaller structures, or fewer reference designs"
        )
    raise RuntimeError(f"a study creation's check failed in its child process:\n{result['error']}")


# -- the helper, and its children ------------------------------------------------------


class _Helper:
    """The server's side of the helper process: its control socket and its process."""

    def __init__(self, control: socket.socket, pid: int, process: subprocess.Popen[bytes] | None):
        self._control = control
        self._pid = pid
        self._process = process
        self._lock = threading.Lock()  # one message at a time, whichever thread sends

    @classmethod
    def start(cls, warm_up: Callable[[], None] | None) -> _Helper:
        ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        if _one_thread() and hasattr(os, "fork"):
            pid = os.fork()
            if pid == 0:  # the helper
                try:
                    ours.close()
                    _helper_main(theirs, warm_up)
                finally:
                    os._exit(0)
            theirs.close()
            return cls(ours, pid, None)
        code = (
            "import sys; sys.path[:] = sys.argv[3:]; "
            "from adservice.creations import _helper_main, _named; import socket; "
            "_helper_main(socket.socket(fileno=int(sys.argv[1])), _named(sys.argv[2]))"
        )
        name = "" if warm_up is None else f"{warm_up.__module__}:{warm_up.__qualname__}"
        process = subprocess.Popen(
            [sys.executable, "-c", code, str(theirs.fileno()), name, *sys.path],
            pass_fds=[theirs.fileno()],
            stdin=subprocess.DEVNULL,
        )
        theirs.close()
        return cls(ours, process.pid, process)

    def alive(self) -> bool:
        if self._process is not None:
            return self._process.poll() is None
        try:
            return os.waitpid(self._pid, os.WNOHANG) == (0, 0)
        except ChildProcessError:
            return False

    def run(self, job: int, budget: CreationBudget, sock: socket.socket) -> None:
        memory = -1 if budget.memory_bytes is None else budget.memory_bytes
        message = _CONTROL.pack(_RUN, job, budget.seconds, memory)
        with self._lock:
            socket.send_fds(self._control, [message], [sock.fileno()])

    def kill(self, job: int) -> None:
        with self._lock, contextlib.suppress(OSError):
            self._control.send(_CONTROL.pack(_KILL, job, 0.0, 0))

    def stop(self) -> None:
        """Close the control socket (the helper kills its children and exits), then make
        sure it is gone."""
        with self._lock:
            self._control.close()
        with contextlib.suppress(ProcessLookupError):
            os.kill(self._pid, signal.SIGKILL)
        with contextlib.suppress(ChildProcessError):
            if self._process is not None:
                self._process.wait()
            else:
                os.waitpid(self._pid, 0)


def _one_thread() -> bool:
    """Whether this process runs one Python thread, so that a fork of it is sound (no
    other thread holds a lock the fork would keep). Native libraries' idle pools do
    not count: OpenBLAS, whose threads numpy starts at import, stops them at a fork."""
    return threading.active_count() == 1


PR_SET_PDEATHSIG = 1


def _die_with_parent() -> None:
    """SIGKILL this process when the thread that started it ends (Linux)."""
    with contextlib.suppress(OSError, AttributeError):
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)


def _named(name: str) -> Callable[[], None] | None:
    """The module-level function ``module:name`` names (None for "")."""
    if not name:
        return None
    import importlib

    module, _, attribute = name.partition(":")
    function: Callable[[], None] = getattr(importlib.import_module(module), attribute)
    return function


def _helper_main(control: socket.socket, warm_up: Callable[[], None] | None) -> None:
    """The helper's loop: fork a child per job, kill the jobs the server abandons, reap
    them; when the control socket closes, kill every child and end."""
    parent = os.getppid()
    _die_with_parent()
    if os.getppid() != parent:  # the server ended before the line above
        return
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the server ends us (a ^C reaches all)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    with contextlib.suppress(ValueError):
        signal.set_wakeup_fd(-1)
    keep = control.fileno()
    os.closerange(3, keep)  # nothing of the server's but its output
    os.closerange(keep + 1, _max_fd())
    gc.freeze()  # the server's objects, never collected here (nor in the children)
    children: dict[int, int] = {}
    warm = False
    try:
        while True:
            readable, _, _ = select.select([control], [], [], 1.0)
            _reap(children)
            if not readable:
                continue
            message, fds, _, _ = socket.recv_fds(control, _CONTROL.size, 1)
            if not message:
                return
            kind, job, seconds, memory = _CONTROL.unpack(message)
            if kind == _KILL:
                pid = next((pid for pid, owner in children.items() if owner == job), None)
                if pid is not None:
                    with contextlib.suppress(ProcessLookupError):
                        os.kill(pid, signal.SIGKILL)
                continue
            if not warm:  # what a job imports, once, before the first fork
                _warm(warm_up)
                warm = True
            sock = socket.socket(fileno=fds[0])
            pid = os.fork()
            if pid == 0:
                try:
                    control.close()
                    _child_main(sock, seconds, None if memory < 0 else memory)
                finally:
                    os._exit(0)
            sock.close()
            children[pid] = job
    finally:
        for pid in children:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        for _ in range(len(children)):
            with contextlib.suppress(ChildProcessError):
                os.wait()


def _max_fd() -> int:
    soft, _ = resource.getrlimit(resource.RLIMIT_NOFILE)
    return soft if soft != resource.RLIM_INFINITY else 65_536


def _reap(children: dict[int, int]) -> None:
    while children:
        try:
            pid, _ = os.waitpid(-1, os.WNOHANG)
        except ChildProcessError:
            children.clear()
            return
        if pid == 0:
            return
        children.pop(pid, None)


def _warm(warm_up: Callable[[], None] | None) -> None:
    """BLAS in one thread, and ``warm_up`` run, so that each child starts with what it
    loaded (its start is then a fork and little more: about 20 ms of a small space's
    130, against about 30 ms more in a child of a helper that never ran the checks)."""
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=1)  # BLAS and OpenMP in one thread, for the children too
    if warm_up is not None:
        warm_up()
    gc.freeze()


def _child_main(sock: socket.socket, seconds: float, memory: int | None) -> None:
    """One job: limits, the work read from ``sock``, its JSON answer written back."""
    parent = os.getppid()
    _die_with_parent()
    if os.getppid() != parent:
        return
    os.nice(NICE)
    cpu = int(seconds) + 1
    resource.setrlimit(resource.RLIMIT_CPU, (cpu, cpu + 1))
    mapped = _mapped_bytes()
    if memory is not None:
        limit = mapped + memory
        with contextlib.suppress(OSError, ValueError):
            resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    sock.setblocking(True)
    (length,) = _LENGTH.unpack(_read_exactly(sock, _LENGTH.size))
    work, args = pickle.loads(_read_exactly(sock, length))
    try:
        answer: dict[str, Any] = {"value": work(*args)}
    except InvalidError as error:
        answer = {"invalid": error.detail, "problems": error.problems}
    except MemoryError:
        answer = {"memory": True}
    except BaseException:
        # a C library's failed allocation comes as its own error (OSQP's code 5)
        near = memory is not None and _peak_bytes() >= mapped + 0.9 * memory
        answer = {"memory": True} if near else {"error": traceback.format_exc()}
    try:
        data = json.dumps(answer, allow_nan=False).encode()
    except (TypeError, ValueError):
        data = json.dumps({"error": traceback.format_exc()}).encode()
    sock.sendall(_LENGTH.pack(len(data)) + data)
    sock.close()


def _mapped_bytes() -> int:
    """This process's virtual memory now (a fork maps all its parent's)."""
    with open("/proc/self/statm") as statm:
        return int(statm.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")


def _peak_bytes() -> int:
    """The most virtual memory this process has mapped."""
    with open("/proc/self/status") as status:
        for line in status:
            if line.startswith("VmPeak:"):
                return int(line.split()[1]) * 1024
    return 0


def _read_exactly(sock: socket.socket, count: int) -> bytes:
    chunks, left = [], count
    while left:
        chunk = sock.recv(min(left, 1 << 20))
        if not chunk:
            raise EOFError("the server closed the job's socket")
        chunks.append(chunk)
        left -= len(chunk)
    return b"".join(chunks)
