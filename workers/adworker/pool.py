"""``--concurrency N``: N workers in child processes, signals passed on, a crashed one
replaced; the rules a Ray pool (:mod:`adworker.raypool`) shares.

The children are forked from the pool's process, which has imported what a task
worker's jobs import (the installed tasks' and learners' modules: torch,
stable-baselines3, PyBullet), once: a child then starts without importing them again
(about 3.5 s of CPU each when every child was a fresh interpreter). A ``--function``
pool imports nothing of the function's in its own process (a module may start threads
as it is imported, which a fork would not carry over): each child imports it. A pool
whose learners train on a GPU starts each child as a fresh interpreter instead: the
pool's process asked torch whether it has the GPU, and CUDA, once initialised there,
cannot be used in a forked child. Each child runs its jobs in a job process of its own
(:mod:`adworker.jobprocess`), forked from it, or a fresh interpreter on a GPU."""

from __future__ import annotations

import gc
import logging
import os
import signal
import sys
import time
from collections.abc import Callable
from typing import Any

from adclient.devices import LEARNER_DEVICE_VARIABLE
from adclient.plugins import LearnerSpec, TaskSpec, catalogue
from adworker.jobprocess import setup_problem
from adworker.runner import factory_problem
from adworker.worker import (
    EXIT_AUTH,
    EXIT_OK,
    EXIT_SETUP,
    Worker,
    WorkerConfig,
    configure_logging,
)

log = logging.getLogger("adworker")


class SharedBudget:
    """A pool's ``--max-jobs``, shared by its processes: each claims a job before leasing
    and gives the claim back when no job came (a Ray pool keeps one in an actor)."""

    def __init__(self, value: Any) -> None:
        self.value = value
        """A ``multiprocessing.Value("i")``, or None: no limit."""

    def claim(self) -> bool:
        if self.value is None:
            return True
        with self.value.get_lock():
            if self.value.value <= 0:
                return False
            self.value.value -= 1
            return True

    def unclaim(self) -> None:
        if self.value is not None:
            with self.value.get_lock():
                self.value.value += 1


def start_worker(
    config: WorkerConfig, claim: Callable[[], bool], unclaim: Callable[[], None]
) -> Worker | None:
    """A pool's worker, or None (logged) when it cannot start: its slot then ends with
    ``EXIT_SETUP``, which stops the pool (a process pool's child, a Ray actor)."""
    try:
        return Worker(config, claim=claim, unclaim=unclaim)
    except Exception as error:
        log.error("cannot start: %s", setup_problem(error))
        return None


def pool_action(code: int | None, signals_seen: int) -> str:
    """What a pool does when one of its workers ended with ``code`` (None: it died
    without one, as a Ray actor whose process or node died): ``"stop"`` the pool (the
    token refused, or it could not start), ``"replace"`` it (it crashed while the pool
    was not stopping), or ``"drop"`` it (it stopped as asked, idle or out of jobs)."""
    if code in (EXIT_AUTH, EXIT_SETUP):
        return "stop"
    if code != EXIT_OK and signals_seen == 0:
        return "replace"
    return "drop"


STOP_SIGNALS = {signal.SIGTERM, signal.SIGINT}


def preload_jobs(config: WorkerConfig) -> None:
    """Import, in the pool's process, what its task workers import to start and run
    their jobs (every installed task's and learner's modules; torch's compiler, which
    torch.optim imports at a learner's first optimizer, 1.7 s of CPU), and freeze the
    objects made so far (a child's collections skip them instead of copying their
    pages). Nothing for a function pool."""
    if config.function is not None:
        return
    installed = catalogue()
    specs: list[TaskSpec | LearnerSpec] = [*installed.tasks.values(), *installed.learners.values()]
    for spec in specs:
        factory_problem(spec)  # one that does not load is logged by each worker
    if "torch" in sys.modules:
        import torch._dynamo  # noqa: F401
    gc.freeze()


def _child_main(config: WorkerConfig, budget: Any, log_level: int) -> None:
    """Entry point of one pool process, started with the stop signals blocked: it takes
    a fresh interpreter's handlers (a forked one has the pool's) before it lets them in."""
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, STOP_SIGNALS)
    configure_logging(log_level, config.worker_id)
    shared = SharedBudget(budget)
    worker = start_worker(config, shared.claim, shared.unclaim)
    if worker is None:
        raise SystemExit(EXIT_SETUP)
    worker.install_signal_handlers()
    # Ctrl-C reaches the whole process group; the parent passes it on as SIGTERM, so
    # a child that also took the SIGINT would count one keypress as two signals.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    raise SystemExit(worker.run())


def run_pool(config: WorkerConfig, concurrency: int, log_level: int = logging.INFO) -> int:
    """Run ``concurrency`` workers in child processes until they stop.

    Signals are passed on to the children (each finishes or abandons its own job).
    A child that dies of something else (a crash inside the physics engine) is
    replaced; one that stops on a refused token, or cannot start, stops the pool.
    """
    import multiprocessing

    forking = os.environ.get(LEARNER_DEVICE_VARIABLE, "cpu") == "cpu"  # not after CUDA
    if forking:
        preload_jobs(config)
    context: Any = multiprocessing.get_context("fork" if forking else "spawn")
    budget = context.Value("i", config.max_jobs) if config.max_jobs is not None else None
    children: dict[int, Any] = {}
    signals_seen = 0

    def start(slot: int) -> None:
        process = context.Process(
            target=_child_main,
            args=(config.for_slot(slot), budget, log_level),
            name=f"adworker-{slot}",
        )
        blocked = signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)
        try:
            process.start()
            children[slot] = process
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, blocked)

    def forward(signum: int, _frame: Any) -> None:
        nonlocal signals_seen
        signals_seen += 1
        log.info("%s: passing it on to %d workers", signal.Signals(signum).name, len(children))
        for process in children.values():
            if process.is_alive() and process.pid is not None:
                os.kill(process.pid, signal.SIGTERM)

    signal.signal(signal.SIGTERM, forward)
    signal.signal(signal.SIGINT, forward)
    for slot in range(concurrency):
        start(slot)
    code = EXIT_OK
    while children:
        time.sleep(0.2)
        for slot, process in list(children.items()):
            if process.is_alive():
                continue
            process.join()
            del children[slot]
            action = pool_action(process.exitcode, signals_seen)
            if action == "stop":
                code = process.exitcode or EXIT_SETUP
                forward(signal.SIGTERM, None)
            elif action == "replace":
                log.error("worker %d died (exit %s); starting another", slot, process.exitcode)
                time.sleep(1.0)
                start(slot)
    return code
