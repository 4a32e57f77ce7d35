"""A worker's jobs run in a process of their own, which the worker ends at the job's limits.

The worker (:mod:`adworker.worker`) leases, keeps the lease alive, reports and tells;
what evaluates a job (its runner: a task's simulation and learner, or a
``--function``) runs in the *job process*, a child the worker starts once and hands
one job at a time over a pipe. Nothing a job does can hold the worker: a learner
inside one C call that never returns (a billion gradient steps, a ``time.sleep``, a
regular expression that backtracks forever) still has its lease kept by the worker's
heartbeat, and the worker kills the job process when the job's time or memory runs
out: the trial is told failed with a message naming the limit, and the next job gets a
new job process. A job whose lease is lost, or that the worker abandons (its stop
grace passed), is cancelled: the runner's ``check()`` raises ``Cancelled`` in the job
process, which is killed if the job has not ended ``CANCEL_SECONDS`` later.

- **Time**: ``--job-seconds`` (default 3600) for any job; a job of an installed task
  whose study sets ``train_steps`` gets at most ``JOB_BASE_SECONDS`` plus
  ``--job-step-seconds`` (default 0.05) for each step it trains and evaluates
  (:meth:`JobLimits.seconds_for`), about 20 times what the built-in learners take.
- **Memory**: ``--job-memory-mb`` (default 2048): each job may grow the job process's
  data (its heap and private writable mappings: what it allocates, not the libraries it
  loads) by this much (``RLIMIT_DATA``, set when the job starts and lifted when it
  ends: Linux). An allocation past it fails there (Python's ``MemoryError``, torch's
  "can't allocate memory"); the trial's message names the limit, and the job process is
  replaced after such a job. Where learners train on a GPU (CUDA maps memory of its
  own, which no rlimit should refuse), the worker watches the job process's resident
  memory instead, every ``POLL_SECONDS``, and kills it when the job has grown it past
  the limit. A job process the system kills (out of memory, a crash in the physics
  engine) is a failed trial naming how it ended.

The job process is forked from the worker (which imports nothing of the jobs' itself
while they run: the worker never runs a job, so no thread or OpenMP pool of theirs is
forked) and keeps what its jobs import (torch, stable-baselines3, PyBullet) from one
job to the next, so a job costs what it did in the worker's own process plus a round
trip of its job and outcome on the pipe (bench/job_process.py). A worker whose
learners train on a GPU, or a Ray actor (whose threads a fork would not carry over),
starts it as a fresh interpreter instead: CUDA, once initialised, cannot be used in a
forked child. It ignores SIGTERM and SIGINT (the worker decides when it ends) and
dies with the worker (Linux). It runs in a process group of its own, and ending a job
kills the group: what the job started (a ``--function``'s simulator) ends with it.
"""

from __future__ import annotations

import contextlib
import ctypes
import logging
import math
import multiprocessing
import os
import resource
import signal
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from adclient.devices import LEARNER_DEVICE_VARIABLE
from adclient.schemas import Job, TaskConfig
from adworker.runner import Cancelled, Outcome, Pruned, Report, Runner, failure_message

log = logging.getLogger("adworker")

JOB_BASE_SECONDS = 60.0
"""What a job with a step budget gets besides its steps: its robot, env, artifacts."""
UNKNOWN_EPISODE_STEPS = 1000
"""The evaluation episode's steps counted for a job whose study does not say."""
POLL_SECONDS = 0.2
"""How often the worker looks at its stop signals and the job's time while it waits."""
CANCEL_SECONDS = 2.0
"""How long a job has to end at its ``check()`` once cancelled, before it is killed."""
START_SECONDS = 300.0
"""How long a new job process gets to import its runner and say it is ready."""
MEMORY_ERRORS = ("MemoryError", "can't allocate memory", "std::bad_alloc", "Cannot allocate")


class JobSetupError(Exception):
    """The job process could not make its runner (a --function that does not import)."""


def setup_problem(error: Exception) -> str:
    """Why a worker cannot start, for its log: a job process's own reason as it gave it."""
    if isinstance(error, JobSetupError):
        return str(error)
    return f"{type(error).__name__}: {error}"


class JobFailed(Exception):
    """The job failed; ``message`` is what its trial is told (the error and where, or the
    limit that stopped it)."""

    def __init__(self, message: str) -> None:
        super().__init__(message)
        self.message = message


@dataclass(frozen=True)
class JobLimits:
    """A worker's limits on each job (``adworker --job-seconds``, ``--job-step-seconds``,
    ``--job-memory-mb``)."""

    seconds: float = 3600.0
    step_seconds: float = 0.05
    memory_mb: int | None = 2048

    def seconds_for(self, job: Job) -> tuple[float, str]:
        """The job's time limit and what sets it: ``--job-seconds``, or less for a job
        of an installed task whose study sets ``train_steps``: ``JOB_BASE_SECONDS`` and
        ``--job-step-seconds`` for each step it trains (``train_steps``, or
        ``transfer_steps`` where more) and evaluates (``eval_episodes`` episodes of
        ``episode_steps``, again at each pruner report)."""
        cap = (self.seconds, f"adworker --job-seconds {self.seconds:g}")
        task = job.task
        if task.external or task.train_steps is None:
            return cap
        steps = job_steps(job)
        own = JOB_BASE_SECONDS + self.step_seconds * steps
        if own >= self.seconds:
            return cap
        why = (
            f"{JOB_BASE_SECONDS:g} s and {self.step_seconds:g} s for each of its {steps:,} "
            f"steps: adworker --job-step-seconds"
        )
        return own, why


def job_steps(job: Job) -> int:
    """The steps a job of an installed task trains and evaluates, as its study sets them."""
    task: TaskConfig = job.task
    training = max(task.train_steps or 0, task.transfer_steps or 0)
    given = task.options.get("episode_steps")  # a stored study's may be anything
    option = given if isinstance(given, int) and not isinstance(given, bool) else None
    episode = task.episode_steps or option or UNKNOWN_EPISODE_STEPS
    evaluations = 1
    if job.pruner.name != "none" and task.train_steps:
        every = job.pruner.report_every or max(1, task.train_steps // 10)
        evaluations += math.ceil(training / every)
    return training + evaluations * task.eval_episodes * max(1, episode)


def start_method(config_method: str | None) -> str:
    """How job processes start: ``config_method`` if given, else a fork, unless the
    learners train on a GPU (a fresh interpreter: ``spawn``)."""
    if config_method is not None:
        return config_method
    return "fork" if os.environ.get(LEARNER_DEVICE_VARIABLE, "cpu") == "cpu" else "spawn"


class JobProcess:
    """The worker's side of its job process: started on first use and after one was
    ended, handed one job at a time by :meth:`run`."""

    def __init__(
        self, make_runner: Callable[[], Runner], limits: JobLimits, method: str = "fork"
    ) -> None:
        self.make_runner = make_runner
        """Makes the runner in the job process (picklable where it is spawned)."""
        self.limits = limits
        self.context: Any = multiprocessing.get_context(method)
        self.watch_resident = os.environ.get(LEARNER_DEVICE_VARIABLE, "cpu") != "cpu"
        """Learners on a GPU: the job's memory is its process's resident memory, watched
        from here (CUDA maps its own memory: no rlimit for the job process)."""
        self.process: Any = None
        self.connection: Any = None
        self.tasks: list[str] = []
        self.learners: list[str] | None = None
        self.ended: int | None = None
        """The exit code of the last job process that ended."""
        self.cpu_seconds = 0.0
        """The CPU time the job process spent on the last job :meth:`run` ran."""
        self.jobs_sent = 0
        """The number of the job sent last: a cancel names the job it is for."""

    def start(self) -> None:
        """A job process, ready to run jobs (its runner made): JobSetupError when it
        cannot make it, with the reason."""
        if self.process is not None:
            return
        mine, theirs = self.context.Pipe()
        process = self.context.Process(
            target=serve,
            args=(theirs, self.make_runner, None if self.watch_resident else self.limits.memory_mb),
            name="adworker-job",
            daemon=False,  # a job may start processes of its own (a --function's pool)
        )
        process.start()
        theirs.close()
        self.process, self.connection = process, mine
        answer = self._answer(START_SECONDS)
        if answer is None or answer[0] != "ready":
            reason = answer[1] if answer is not None else f"its process {self._ending()}"
            self.close()
            raise JobSetupError(reason)
        self.tasks, self.learners = answer[1], answer[2]

    def run(
        self,
        job: Job,
        workdir: Path,
        *,
        report: Report,
        stop: Callable[[], str | None],
    ) -> Outcome:
        """The job's outcome. Raises :class:`Pruned` as the runner did, :class:`JobFailed`
        when it failed or was ended at a limit (its job process then replaced), and
        :class:`Cancelled` when ``stop()`` gives a reason (the lease lost, the worker
        stopping): the runner's ``check()`` raises it in the job process, which is
        killed if the job has not ended ``CANCEL_SECONDS`` later. ``report`` sends the
        runner's intermediate values."""
        if self.process is not None and not self.process.is_alive():
            self._reap()  # it ended between jobs (killed by the system): a new one
        self.start()
        self.cpu_seconds = 0.0
        self.jobs_sent += 1
        seconds, why = self.limits.seconds_for(job)
        self.connection.send(("job", job.model_dump_json(), str(workdir), self.jobs_sent))
        ends = time.monotonic() + seconds
        resident = self._resident() if self.watch_resident else None
        cancelled: tuple[str, float] | None = None
        while True:
            reason = stop() if cancelled is None else None
            if reason is not None:
                self._send(("cancel", self.jobs_sent))
                cancelled = (reason, time.monotonic() + CANCEL_SECONDS)
            if cancelled is not None and time.monotonic() >= cancelled[1]:
                self.close(kill=True)
                raise Cancelled(cancelled[0])
            grown = self._grown(resident)
            if grown is not None:
                self.close(kill=True)
                raise JobFailed(grown)
            left = ends - time.monotonic()
            if left <= 0:
                self.close(kill=True)
                raise JobFailed(
                    f"stopped at the job's time limit of {seconds:g} s ({why}): its "
                    "learner or function was still running"
                )
            message = self._answer(min(POLL_SECONDS, left))
            if message is None:
                if self.process is None:
                    raise JobFailed(self._died_message())
                continue
            kind = message[0]
            if kind == "report":
                if cancelled is None:  # else the cancel is its answer
                    lost = self._pass_report(report, message[1], message[2])
                    if lost is not None:
                        cancelled = (lost, time.monotonic() + CANCEL_SECONDS)
                continue
            self.cpu_seconds = message[-1]
            if cancelled is not None:  # however it ended, it is not reported
                raise Cancelled(cancelled[0])
            if kind == "complete":
                return message[1]
            if kind == "pruned":
                raise pruned(message[1])
            if kind == "cancelled":
                raise Cancelled(message[1])
            if message[2]:  # failed at its memory limit: the next job gets a fresh process
                self.close()
            raise JobFailed(message[1])

    def _resident(self) -> int | None:
        """The job process's resident memory (bytes), if it can be read."""
        try:
            with open(f"/proc/{self.process.pid}/statm") as statm:
                return int(statm.read().split()[1]) * resource.getpagesize()
        except (OSError, AttributeError, IndexError, ValueError):
            return None

    def _grown(self, resident: int | None) -> str | None:
        """Why the job is stopped for its memory (learners on a GPU): its process's
        resident memory grew past the limit since the job began; None while it has not."""
        memory = self.limits.memory_mb
        now = self._resident() if resident is not None and memory else None
        if now is None or resident is None or memory is None:
            return None
        grown = (now - resident) // (1024 * 1024)
        if grown <= memory:
            return None
        return (
            f"stopped at the job's memory limit of {memory} MB (adworker --job-memory-mb): "
            f"its process's resident memory grew by {grown} MB"
        )

    def _pass_report(self, report: Report, step: int, value: float) -> str | None:
        """Report for the job process and give it the answer; why the job is cancelled
        when the report says it is (then the answer is the cancel)."""
        try:
            report(step, value)
        except Pruned as stopped:
            self._send(("stop", stopped.pause))
        except Cancelled as lost:
            self._send(("cancel", self.jobs_sent))
            return str(lost)
        else:
            self._send(("go",))
        return None

    def _send(self, message: tuple[Any, ...]) -> None:
        """A message to the job process; none to one that has ended (its end is read
        next, by :meth:`_answer`)."""
        with contextlib.suppress(OSError):
            self.connection.send(message)

    def _answer(self, timeout: float) -> Any:
        """The job process's next message within ``timeout`` s; None when there is none
        yet, or when it has ended (then ``process`` is None and ``ended`` says how)."""
        try:
            if not self.connection.poll(timeout):
                return None
            return self.connection.recv()
        except (EOFError, OSError):
            self._reap()
            return None

    def _reap(self) -> None:
        process = self.process
        if process is None:
            return
        process.join(5.0)
        if process.is_alive():
            process.kill()
            process.join()
        self.ended = process.exitcode
        self.connection.close()
        self.process = self.connection = None

    def _ending(self) -> str:
        code = getattr(self, "ended", None)
        if code is None:
            return "did not answer"
        if code < 0:
            try:
                return f"was killed by {signal.Signals(-code).name}"
            except ValueError:
                return f"was killed by signal {-code}"
        return f"exited with status {code}"

    def _died_message(self) -> str:
        memory = self.limits.memory_mb
        within = f" (its memory limit is {memory} MB: adworker --job-memory-mb)" if memory else ""
        return (
            f"the job's process {self._ending()} before it finished: the system may have "
            f"run out of memory, or the simulator or learner crashed{within}"
        )

    def close(self, *, kill: bool = False) -> None:
        """End the job process: at once (``kill``), else after it has left its loop."""
        process = self.process
        if process is None:
            return
        if kill:  # with what the job started (its process group: see serve)
            with contextlib.suppress(OSError):
                os.killpg(process.pid, signal.SIGKILL)
            process.kill()
        else:
            try:
                self.connection.send(("exit",))
            except OSError:
                process.kill()
        self._reap()


def pruned(fields: dict[str, Any]) -> Pruned:
    """A :class:`Pruned` rebuilt from the job process's fields of one."""
    stopped = Pruned(fields["step"], fields["value"], pause=fields["pause"])
    for name in ("checkpoint", "transfer_from", "metrics", "budget"):
        setattr(stopped, name, fields[name])
    return stopped


# ------------------------------------------------------------ the job process's side


def serve(connection: Any, make_runner: Callable[[], Runner], memory_mb: int | None) -> None:
    """The job process: make the runner, say what it serves, then run each job it is
    handed until told to exit or the worker is gone."""
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _die_with_parent()
    with contextlib.suppress(OSError):  # a group of its own: a kill ends what a job started
        os.setpgid(0, 0)
    try:
        runner = make_runner()
        connection.send(("ready", runner.tasks(), runner.learners()))
    except Exception as error:
        connection.send(("setup-error", f"{type(error).__name__}: {error}"))
        return
    while True:
        try:
            message = connection.recv()
        except (EOFError, OSError):
            return
        if message[0] == "cancel":  # for a job that had ended already
            continue
        if message[0] != "job":
            return
        job = Job.model_validate_json(message[1])
        started = time.process_time()
        result = _run_job(connection, runner, job, Path(message[2]), message[3], memory_mb)
        connection.send((*result, time.process_time() - started))


def _run_job(
    connection: Any, runner: Runner, job: Job, workdir: Path, number: int, memory_mb: int | None
) -> tuple[Any, ...]:
    def next_message(wait: bool) -> Any:
        """The worker's next message (None: none yet, unless ``wait``), past cancels of
        earlier jobs; Cancelled for a cancel of this one."""
        while wait or connection.poll():
            message = connection.recv()
            if message[0] != "cancel":
                return message
            if message[1] == number:
                raise Cancelled("the worker cancelled the job")
        return None

    def check() -> None:
        next_message(wait=False)  # only a cancel comes unasked

    def report(step: int, value: float) -> None:
        connection.send(("report", step, value))
        told = next_message(wait=True)
        if told[0] == "stop":
            raise Pruned(step, value, pause=told[1])

    lifted = _limit_memory(memory_mb)
    try:
        outcome = runner(job, workdir, check, report)
    except Cancelled as stopped:
        return ("cancelled", str(stopped))
    except Pruned as stopped:
        fields = {
            name: getattr(stopped, name)
            for name in ("step", "value", "pause", "checkpoint", "transfer_from", "metrics")
        }
        return ("pruned", {**fields, "budget": stopped.budget})
    except Exception as error:
        message = failure_message(error)
        at_limit = memory_mb is not None and any(text in message for text in MEMORY_ERRORS)
        if at_limit:
            message = (
                f"the job ran out of memory at its limit of {memory_mb} MB "
                f"(adworker --job-memory-mb): {message}"
            )
        return ("failed", message, at_limit)
    finally:
        lifted()
    return ("complete", outcome)


def _limit_memory(memory_mb: int | None) -> Callable[[], None]:
    """Let the job grow this process's data (its heap and private writable mappings:
    what it allocates, not the libraries it maps) by ``memory_mb`` at most
    (``RLIMIT_DATA``); the function that lifts the limit again. Nothing where the data
    size cannot be read (not Linux)."""
    if memory_mb is None:
        return lambda: None
    try:
        with open("/proc/self/status") as status:
            fields = dict(line.split(":", 1) for line in status if ":" in line)
        size = int(fields["VmData"].split()[0]) * 1024
    except (OSError, KeyError, ValueError):
        return lambda: None
    soft, hard = resource.getrlimit(resource.RLIMIT_DATA)
    limit = size + memory_mb * 1024 * 1024
    if hard != resource.RLIM_INFINITY:
        limit = min(limit, hard)
    resource.setrlimit(resource.RLIMIT_DATA, (limit, hard))
    return lambda: resource.setrlimit(resource.RLIMIT_DATA, (soft, hard))


def _die_with_parent() -> None:
    """Linux: this process is killed when the worker that started it dies (a hung job
    would otherwise outlive a worker killed with SIGKILL)."""
    if not sys.platform.startswith("linux"):
        return
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        return
    if os.getppid() == 1:  # the worker died before the call
        os._exit(1)
