"""The worker loop: lease a job, keep its lease alive, evaluate it, report, repeat.

One :class:`Worker` runs jobs one at a time; ``--concurrency N`` runs N of them in child
processes (:func:`adworker.pool.run_pool`). What evaluates a job is its runner
(:mod:`adworker.runner`): the installed tasks, or a function (``--function``); the loop
is the same for both, and leases only the runner's tasks. The runner lives in the
worker's job process (:mod:`adworker.jobprocess`), which the worker kills past the job's
time or memory limit (the trial told failed, naming it) or when the job is dropped.
The rules it keeps:

- Network errors and 5xx answers are retried with backoff (the SDK retries each
  request a few times; the loop keeps waiting, with a growing pause, while the server
  stays away). A result is not thrown away lightly: a tell is retried for
  ``TELL_PATIENCE`` seconds.
- 401/403 stop the worker with a message naming the token: more tries cannot help.
- A heartbeat thread extends the lease while the job runs. A 409 on it means the
  lease is lost (it expired and another worker may have the job): the evaluation is
  cancelled at its next check and nothing is reported.
- An exception inside the evaluation (a bad design, a physics or training failure)
  becomes a ``failed`` tell carrying the error; the worker goes on.
- Intermediate values (a learner's evaluation every ``pruner.report_every`` steps, a
  function's ``job.report``) are reported as they come; when the study's pruner says
  stop, training stops there and the trial is told ``pruned`` with its last value. A
  report that fails for a network reason is skipped (the job goes on); a 409 on one is
  a lost lease, as on a heartbeat.
- When it says pause (ASHA with promotion), a learner that can resume (the SB3 ones)
  hands over its checkpoint: the worker uploads it as the trial's ``checkpoint.zip``
  and pauses the trial (else tells it pruned). A promoted trial's job (``job.resume``)
  downloads that checkpoint first and trains on from it.
- SIGTERM/SIGINT: stop leasing, finish the current job within ``stop_grace`` seconds,
  report it, exit 0. A second one, or the grace run out, abandons the current job (its
  job process killed, wherever it was), gives its lease back (the server queues the
  trial for another worker at once, without counting the attempt; if that call fails
  the lease simply expires) and exits.
- Files: a job writes only in its own folder, removed when the job ends however it
  ends (unless ``--keep-files``), inside the worker's folder (``--workdir``, else a
  temporary ``adworker-*`` made at its first job and removed when it stops). A worker
  that could not clean up (SIGKILL, out of memory) leaves its temporary folder; the
  next worker to start on the machine removes it (:mod:`adworker.workdirs`).
"""

from __future__ import annotations

import functools
import logging
import math
import os
import random
import shutil
import signal
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from adclient import __version__
from adclient.client import Client
from adclient.errors import (
    ApiError,
    Conflict,
    Forbidden,
    NotFound,
    Unauthorized,
    Unavailable,
    UnreadableJob,
)
from adclient.pruning import CHECKPOINT_ARTIFACT, ReportResponse
from adclient.schemas import SHARED_ARTIFACT, Job
from adworker.heartbeat import Heartbeat
from adworker.job_metrics import Rates, spent
from adworker.jobprocess import JobFailed, JobLimits, JobProcess, start_method
from adworker.runner import (
    MESSAGE_LIMIT,
    Artifact,
    Cancelled,
    Outcome,
    Pruned,
    Runner,
    failure_message,
)
from adworker.sharing import advance_shared
from adworker.sources import fetch_start
from adworker.workdirs import make_workdir, remove_abandoned_workdirs

log = logging.getLogger("adworker")

TELL_PATIENCE = 300.0
"""Seconds a finished job's tell keeps being retried while the server is unreachable."""
MAX_IDLE_BACKOFF = 30.0
EXIT_OK = 0
EXIT_AUTH = 4
"""The server refused the token (not 2: that is a usage error, as every Typer CLI's)."""
EXIT_SETUP = 3
"""The runner could not be made (a --function that does not import...)."""


class AuthError(Exception):
    """The server refused the token: the worker cannot do anything useful."""


def default_worker_id() -> str:
    return f"{socket.gethostname()}-{os.getpid()}"


@dataclass
class WorkerConfig:
    server: str
    token: str | None = None
    worker_id: str = field(default_factory=default_worker_id)
    poll: float = 2.0
    max_jobs: int | None = None
    idle_exit: float | None = None
    """Exit after this many seconds without work (None: never)."""
    workdir: Path | None = None
    keep_files: bool = False
    render: bool = True
    ca_bundle: Path | None = None
    """A PEM CA bundle to check an https server's certificate with (None: the system's)."""
    function: str | None = None
    """``module:callable`` that scores each job (``--function``); None: installed tasks."""
    task: str | None = None
    """The task name a function serves."""
    app_dir: Path | None = None
    """Where a function's module is imported from, before sys.path."""
    limits: JobLimits = field(default_factory=JobLimits)
    """Each job's time and memory (``--job-seconds``, ``--job-step-seconds``,
    ``--job-memory-mb``: :mod:`adworker.jobprocess`)."""
    stop_grace: float = 25.0
    """Seconds the current job gets to finish after a stop signal (``--stop-grace``)."""
    job_start: str | None = None
    """How the job process starts: ``fork``, ``spawn``, None for the device's way."""

    def for_slot(self, slot: int) -> WorkerConfig:
        """The config of one of a pool's workers (a process, or a Ray actor): its own
        name, and no job count of its own (the pool's budget counts them all)."""
        return WorkerConfig(
            **{**self.__dict__, "worker_id": f"{self.worker_id}-{slot}", "max_jobs": None}
        )


def make_runner(config: WorkerConfig) -> Runner:
    """The configured runner, made in the job process when the worker starts: a
    function's module is imported then, so a typo stops the worker at start, not at
    its first job."""
    if config.function is None:
        from adworker.evaluate import TaskRunner

        return TaskRunner(render=config.render)
    from adworker.functions import FunctionRunner

    if config.task is None:
        raise ValueError("--function needs --task: the name of the task it serves")
    return FunctionRunner(config.function, config.task, config.app_dir)


def job_process_runner(config: WorkerConfig, log_level: int) -> Runner:
    """A job process's runner; one started as a fresh interpreter logs as its worker."""
    if not logging.getLogger().handlers:
        configure_logging(log_level, config.worker_id)
    return make_runner(config)


class Worker:
    """Leases and evaluates jobs, one at a time; see the module docstring."""

    def __init__(
        self,
        config: WorkerConfig,
        *,
        client: Client | None = None,
        runner: Runner | None = None,
        claim: Callable[[], bool] | None = None,
        unclaim: Callable[[], None] | None = None,
    ) -> None:
        self.config = config
        self.client = client or Client(
            config.server,
            config.token,
            verify=str(config.ca_bundle) if config.ca_bundle is not None else True,
        )
        make: Callable[[], Runner] = (
            functools.partial(job_process_runner, config, logging.getLogger().level)
            if runner is None
            else lambda: runner
        )
        method = start_method(config.job_start)
        self.jobs = JobProcess(make, config.limits, method if runner is None else "fork")
        """Where jobs run (:mod:`adworker.jobprocess`); started now, so a runner that
        cannot be made stops the worker at start (JobSetupError)."""
        self.jobs.start()
        self.stopping = threading.Event()
        """Finish the current job (within ``stop_grace``), then exit."""
        self.abandon = threading.Event()
        """Drop the current job now and exit."""
        self._grace_ends = math.inf
        self.rates = Rates()
        self._claim = claim
        self._unclaim = unclaim
        self._own_workdir = config.workdir is None
        self.workdir: Path | None = config.workdir
        """Where job folders go: ``--workdir``, else a temporary folder made at the first
        job (:meth:`_workdir`) and removed when :meth:`run` ends."""
        self._workdir_lock: int | None = None

    # ------------------------------------------------------------------ signals

    def install_signal_handlers(self) -> None:
        signal.signal(signal.SIGTERM, self._on_signal)
        signal.signal(signal.SIGINT, self._on_signal)

    def _on_signal(self, signum: int, _frame: Any) -> None:
        self.signal(signal.Signals(signum).name)

    def signal(self, name: str = "SIGTERM") -> None:
        """A stop signal, from this process's handler or a pool's driver: the first
        finishes the current job, a second abandons it (its lease is given back)."""
        if self.stopping.is_set():
            log.warning("%s again: abandoning the current job and exiting", name)
            self.abandon.set()
        else:
            grace = self.config.stop_grace
            log.info(
                "%s: finishing the current job within %g s (--stop-grace), then exiting "
                "(again to abandon it now)",
                name,
                grace,
            )
            self._grace_ends = time.monotonic() + grace
            self.stopping.set()

    def _past_grace(self) -> bool:
        """Whether the current job is to be dropped: a second stop signal, or the first's
        grace has run out (then it is dropped now)."""
        if not self.abandon.is_set() and time.monotonic() >= self._grace_ends:
            log.warning(
                "the stop grace of %g s (--stop-grace) ran out: abandoning the current job",
                self.config.stop_grace,
            )
            self.abandon.set()
        return self.abandon.is_set()

    # --------------------------------------------------------------------- loop

    def run(self) -> int:
        """Work until told to stop, out of jobs (``max_jobs``) or idle (``idle_exit``)."""
        config = self.config
        tasks, learners = self.jobs.tasks, self.jobs.learners
        log.info(
            "worker %s serving %s: tasks %s, learners %s",
            config.worker_id,
            config.server,
            tasks,
            "any" if learners is None else learners,
        )
        idle_since = time.monotonic()
        failures = 0
        if self._own_workdir:
            remove_abandoned_workdirs()
        try:
            while not self.stopping.is_set():
                if config.max_jobs is not None and self.rates.jobs >= config.max_jobs:
                    log.info("done %d jobs (--max-jobs)", self.rates.jobs)
                    break
                if self._claim is not None and not self._claim():
                    log.info("the pool's job budget is spent")
                    break
                try:
                    job = self.client.lease(config.worker_id, tasks=tasks, learners=learners)
                except (Unauthorized, Forbidden) as exc:
                    raise AuthError(str(exc)) from exc
                except ApiError as exc:
                    job = None
                    failures += 1
                    pause = min(MAX_IDLE_BACKOFF, config.poll * 2 ** min(failures, 6))
                    if isinstance(exc, UnreadableJob):  # a job leased and failed: counted
                        self._refuse(exc)
                        log.warning("next lease in %.1f s", pause)
                    else:
                        log.warning("lease failed (%s); next try in %.1f s", exc, pause)
                        self._unclaim_job()
                    self._sleep(pause * (0.5 + random.random() / 2))
                    continue
                failures = 0
                if job is None:
                    self._unclaim_job()
                    idle = time.monotonic() - idle_since
                    if config.idle_exit is not None and idle >= config.idle_exit:
                        log.info("no work for %.0f s (--idle-exit)", idle)
                        break
                    self._sleep(config.poll)
                    continue
                self.process(job)
                idle_since = time.monotonic()
                if self.abandon.is_set():
                    break
        except AuthError as exc:
            log.error(
                "the server refused this worker's token: %s. Pass a worker or admin token "
                "with --token or AD_TOKEN.",
                exc,
            )
            return EXIT_AUTH
        finally:
            self.jobs.close()
            log.info("worker %s stopping: %s", config.worker_id, self.rates.line())
            if self._own_workdir and self.workdir is not None and not config.keep_files:
                shutil.rmtree(self.workdir, ignore_errors=True)
                self.workdir = None
            if self._workdir_lock is not None:
                os.close(self._workdir_lock)
                self._workdir_lock = None
        return EXIT_OK

    def _workdir(self) -> Path:
        """The folder job folders go in: ``--workdir``, else this worker's temporary
        folder, made now if it has none, locked while the process lives (unless its
        files are kept: a kept folder is never taken for an abandoned one)."""
        if self.workdir is None:
            self.workdir, self._workdir_lock = make_workdir(lock=not self.config.keep_files)
        return self.workdir

    def _unclaim_job(self) -> None:
        if self._unclaim is not None:
            self._unclaim()

    def _sleep(self, seconds: float) -> None:
        self.stopping.wait(seconds)

    # ---------------------------------------------------------------------- job

    def process(self, job: Job) -> str:
        """Evaluate and report one job; returns 'complete', 'failed', 'pruned', 'paused'
        or 'abandoned'."""
        label = f"trial {job.trial_id} (study {job.study_id} #{job.number}, attempt {job.attempt})"
        log.info("%s: task %s", label, job.task.name)
        jobdir = self._workdir() / f"trial-{job.trial_id}-attempt-{job.attempt}"
        try:
            return self._process(job, label, jobdir)
        finally:
            if not self.config.keep_files:
                shutil.rmtree(jobdir, ignore_errors=True)

    def _process(self, job: Job, label: str, jobdir: Path) -> str:
        started, cpu_started = time.monotonic(), time.process_time()
        with Heartbeat(self.client, job, self.config.worker_id) as heartbeat:

            def stop() -> str | None:
                if heartbeat.lost.is_set():
                    return heartbeat.reason
                if self._past_grace():
                    return "worker shutting down"
                return None

            def check() -> None:
                reason = stop()
                if reason is not None:
                    raise Cancelled(reason)

            def report(step: int, value: float) -> None:
                check()
                answer = self._reported(job, label, step, value)
                if answer.should_stop:
                    raise Pruned(step, value, pause=answer.pause)

            try:
                fetch_start(self.client, job, jobdir)
                outcome = self.jobs.run(job, jobdir, report=report, stop=stop)
            except Cancelled as exc:
                log.warning("%s: abandoned (%s); not reported", label, exc)
                result = "abandoned"
                unreported = True
            except Pruned as exc:
                busy = time.monotonic() - started
                self.rates.jobs += 1
                self.rates.busy_seconds += busy
                log.info("%s: %s after %.1f s; %s", label, exc, busy, self.rates.line())
                metrics = spent(
                    job,
                    {
                        "train_steps": float(exc.step),
                        "time_total_s": busy,
                        "time_cpu_s": self._cpu_since(cpu_started),
                        **exc.metrics,
                    },
                )
                checkpoint = Artifact(CHECKPOINT_ARTIFACT, "application/zip", exc.checkpoint or b"")
                if exc.checkpoint is not None and self._upload(job, heartbeat, label, [checkpoint]):
                    result = "paused"
                    step, value, source, budget = exc.step, exc.value, exc.transfer_from, exc.budget

                    def pause() -> object:
                        return self.client.pause(
                            job.trial_id,
                            worker_id=self.config.worker_id,
                            step=step,
                            value=value,
                            metrics=metrics,
                            transfer_from=source,
                            budget=budget,
                        )

                    unreported = not self._deliver(label, pause)
                else:
                    result = "pruned"
                    unreported = not self._report(
                        job,
                        label,
                        state="pruned",
                        value=exc.value,
                        metrics=metrics,
                        worker_id=self.config.worker_id,
                    )
            except Exception as exc:
                message = exc.message if isinstance(exc, JobFailed) else failure_message(exc)
                message = message[:MESSAGE_LIMIT]
                log.error("%s: evaluation failed: %s", label, message.splitlines()[0])
                self.rates.jobs += 1
                self.rates.failed += 1
                result = "failed"
                unreported = not self._report(
                    job,
                    label,
                    state="failed",
                    message=message,
                    worker_id=self.config.worker_id,
                )
            else:
                busy = time.monotonic() - started
                self.rates.jobs += 1
                self.rates.sim_steps += outcome.metrics.get("sim_steps", 0.0)
                self.rates.busy_seconds += busy
                result = "complete"
                if self._upload(job, heartbeat, label, outcome.artifacts):
                    self._share(job, label, outcome)
                cpu = self._cpu_since(cpu_started)
                unreported = not self._report(
                    job,
                    label,
                    value=outcome.value,
                    metrics=spent(job, {**outcome.metrics, "time_cpu_s": cpu}),
                    worker_id=self.config.worker_id,
                    transfer_from=outcome.transfer_from,
                )
                log.info("%s: %s in %.1f s; %s", label, outcome.summary, busy, self.rates.line())
        if unreported and self.abandon.is_set() and not heartbeat.lost.is_set():
            self._release(job, label)
        return result

    def _cpu_since(self, started: float) -> float:
        """The CPU seconds of the current job: this process's since ``started`` and its
        job process's."""
        return time.process_time() - started + self.jobs.cpu_seconds

    def _reported(self, job: Job, label: str, step: int, value: float) -> ReportResponse:
        """Report an intermediate value; whether the study's pruner stops (or pauses) the
        trial. A lost lease cancels the job; a report the server cannot take now is
        skipped."""
        try:
            return self.client.report_answer(
                job.trial_id, step, value, worker_id=self.config.worker_id
            )
        except (Conflict, NotFound) as exc:
            raise Cancelled(f"lease lost: {exc}") from exc
        except (Unauthorized, Forbidden) as exc:
            raise Cancelled(f"report refused: {exc}") from exc
        except ApiError as exc:
            log.warning("%s: report at step %d skipped (%s)", label, step, exc)
            return ReportResponse(should_stop=False)

    def _share(self, job: Job, label: str, outcome: Outcome) -> None:
        """A ``task.transfer: shared`` job's update (uploaded with its artifacts) made
        the study's next shared controller, before the tell ends the lease."""
        mine = next((a.data for a in outcome.artifacts if a.name == SHARED_ARTIFACT), None)
        if mine is None or outcome.shared_start is None:
            return
        try:
            advance_shared(
                self.client,
                job,
                worker_id=self.config.worker_id,
                mine=mine,
                start=outcome.shared_start,
                label=label,
            )
        except (Unauthorized, Forbidden) as exc:
            raise AuthError(str(exc)) from exc
        except Exception as exc:  # the trial's result is told all the same
            log.error("%s: shared-controller update not offered: %s", label, failure_message(exc))

    def _refuse(self, exc: UnreadableJob) -> None:
        """A job leased that this worker cannot read (a server newer than it, a study
        using a setting it does not know): the trial fails saying so, where its study's
        owner reads it, and the lease loop backs off as after a failed lease, so a
        newer worker may take the study's next trials (docs/worker.md, "Workers older
        than the server"). It counts as a job done (``--max-jobs``, a pool's budget), as
        it counts as one of the study's trials."""
        message = (
            f"adworker {__version__} on {self.config.worker_id} cannot read this job: "
            f"{exc.detail}. The server is newer than this worker and the study uses a "
            "setting it does not know: upgrade the worker (pip install -U "
            "'activedesign[worker]')."
        )
        log.error("%s", message)
        self.rates.jobs += 1
        self.rates.failed += 1
        trial_id = exc.trial_id
        if trial_id is None:
            return
        self._deliver(
            f"trial {trial_id}",
            lambda: self.client.tell(
                trial_id,
                state="failed",
                message=message[:MESSAGE_LIMIT],
                worker_id=self.config.worker_id,
            ),
        )

    def _release(self, job: Job, label: str) -> None:
        """Hand the lease back so the trial is queued now, not when the lease expires."""
        try:
            self.client.release(job.trial_id, self.config.worker_id)
        except ApiError as exc:
            log.warning("%s: lease not given back (%s); it will expire", label, exc)
        else:
            log.info("%s: lease given back; the trial is queued for another worker", label)

    def _upload(
        self, job: Job, heartbeat: Heartbeat, label: str, artifacts: list[Artifact]
    ) -> bool:
        """Store the artifacts while the lease holds; whether all were stored."""
        stored = True
        for artifact in artifacts:
            if heartbeat.lost.is_set() or self._past_grace():
                return False
            try:
                self.client.put_artifact(
                    job.trial_id,
                    artifact.name,
                    artifact.data,
                    artifact.content_type,
                    worker_id=self.config.worker_id,
                )
            except (Unauthorized, Forbidden) as exc:
                raise AuthError(str(exc)) from exc
            except ApiError as exc:
                log.warning("%s: artifact %s not stored (%s)", label, artifact.name, exc)
                stored = False
        return stored

    def _report(self, job: Job, label: str, **tell: Any) -> bool:
        """Tell the result; False only when shutting down before it was told."""
        return self._deliver(label, lambda: self.client.tell(job.trial_id, **tell))

    def _deliver(self, label: str, send: Callable[[], object]) -> bool:
        """Send a job's result (a tell, a pause), retried while the server is away;
        False only when shutting down before it was sent."""
        deadline = time.monotonic() + TELL_PATIENCE
        pause = 1.0
        while True:
            if self._past_grace():
                log.warning("%s: shutting down before the result was reported", label)
                return False
            try:
                send()
                return True
            except (Unauthorized, Forbidden) as exc:
                raise AuthError(str(exc)) from exc
            except (Conflict, NotFound) as exc:
                log.warning("%s: result not accepted (%s)", label, exc)
                return True
            except Unavailable as exc:
                if time.monotonic() > deadline:
                    log.error("%s: result lost, the server stayed away: %s", label, exc)
                    return True
                log.warning("%s: tell failed (%s); retrying in %.0f s", label, exc, pause)
                self.abandon.wait(pause)
                pause = min(pause * 2, MAX_IDLE_BACKOFF)
            except ApiError as exc:
                log.error("%s: result refused: %s", label, exc)
                return True


def configure_logging(level: int, worker_id: str) -> None:
    logging.basicConfig(
        level=level,
        format=f"%(asctime)s %(levelname)s [{worker_id}] %(message)s",
        datefmt="%H:%M:%S",
        force=True,
    )
    # httpx logs every request at INFO: too much for a loop that polls.
    logging.getLogger("httpx").setLevel(max(level, logging.WARNING))
