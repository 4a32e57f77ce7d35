"""Workers on a Ray cluster: ``adworker --ray local|ADDRESS [--concurrency N]``.

Each of the N workers is a Ray actor that runs :class:`adworker.worker.Worker`'s loop,
the one a process worker runs: it leases a job of its tasks, keeps the lease alive from
its heartbeat thread, evaluates the job, uploads its artifacts and tells the score, with
the same retries. Nothing about leasing is Ray's: the cluster only places the workers
and starts new ones. An actor holds one job's resources (:func:`job_resources`), so Ray
places as many on a node as its CPUs and GPUs allow and keeps the rest pending until
there is room.

A Ray worker process or node that dies takes its job with it, unreported: the trial's
lease then expires (``AD_LEASE_SECONDS``), the server's sweeper queues it again and
another worker leases it, as when a process worker is killed. The driver (the
``adworker`` process) sees the actor gone and starts another in its slot. SIGTERM or
Ctrl-C to the driver: every actor finishes and reports its job, then the driver exits;
a second one: they abandon their jobs and give the leases back. The driver's actors
belong to it: when the driver itself dies, Ray ends them and their leases expire.

``local`` starts a Ray cluster on this machine for the driver's lifetime, on loopback;
an address (``HOST:PORT`` of the cluster's GCS, ``auto``, or ``ray://HOST:PORT``)
joins a running one, whose nodes must have the project's ``worker`` extra (and a
``--function``'s module) installed. This module imports Ray: only ``adworker --ray``
imports it.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import os
import signal
import socket
import sys
import time
from dataclasses import dataclass
from typing import Any

from adworker.pool import pool_action, start_worker
from adworker.worker import EXIT_OK, EXIT_SETUP, WorkerConfig, configure_logging

# Read when Ray is imported: every actor's log line reaches the driver as it was written,
# not folded into "[repeated Nx across cluster]".
os.environ.setdefault("RAY_DEDUP_LOGS", "0")
if not sys.stderr.isatty():
    os.environ.setdefault("RAY_COLOR_PREFIX", "0")  # no colour codes in log files

log = logging.getLogger("adworker")

LOCAL = "local"
LOCAL_OBJECT_STORE_BYTES = 200 * 1024 * 1024
"""A local cluster's object store: jobs and results go over HTTP, never through it."""
CONNECT_SECONDS = 10.0
"""How long a cluster's address gets to answer before the driver gives up."""
PENDING_REPORT_SECONDS = 30.0
"""How often the driver says which actors still wait for the cluster's resources."""
LOG_DRAIN_SECONDS = 1.0
"""How long the driver waits, once its actors have ended, for their last log lines (Ray
forwards them from the nodes' log files) before it leaves the cluster."""
THREAD_VARIABLES = ("OMP_NUM_THREADS", "MKL_NUM_THREADS")


class RaySetupError(Exception):
    """The pool cannot start (Ray missing, no cluster there, a --function that does not
    import): a message for the user."""


@dataclass(frozen=True)
class JobResources:
    """What one job holds on the cluster: Ray's ``num_cpus`` and ``num_gpus``."""

    cpus: float
    gpus: float

    def options(self) -> dict[str, float]:
        return {"num_cpus": self.cpus, "num_gpus": self.gpus}


def job_resources(
    learner_device: str, *, function: bool, cpus: float | None = None, gpus: float | None = None
) -> JobResources:
    """One job's resources, from what the worker's jobs run: a task's simulation and its
    learner train on one CPU thread (adworker pins torch and BLAS to one thread per job),
    and the stable-baselines3 learners' networks take a GPU when ``learner_device`` is
    ``cuda``; a ``--function`` job is one call on one CPU and takes no GPU (a function
    that uses one says so with ``gpus``). ``cpus``/``gpus`` override (fractions share a
    GPU between jobs)."""
    default_gpus = 1.0 if learner_device == "cuda" and not function else 0.0
    return JobResources(
        cpus=1.0 if cpus is None else cpus, gpus=default_gpus if gpus is None else gpus
    )


def _import_ray() -> Any:
    try:
        import ray
    except ImportError as error:
        raise RaySetupError(
            f"--ray needs Ray, which is not installed here ({error}); install it with "
            "pip install 'activedesign[ray]' (or pip install ray)"
        ) from None
    return ray


def _check_reachable(address: str) -> None:
    """Fail fast, with the reason, on an address where nothing listens: Ray itself keeps
    retrying a dead address for minutes."""
    if address == "auto":
        return
    target = address.removeprefix("ray://")
    host, separator, port_text = target.rpartition(":")
    if not separator or not host or not port_text.isdigit():
        raise RaySetupError(
            f"--ray {address!r} is not a cluster address: give 'local', 'auto', HOST:PORT "
            "(the head node's GCS port, 6379 by default) or ray://HOST:PORT"
        )
    try:
        with socket.create_connection((host.strip("[]"), int(port_text)), CONNECT_SECONDS):
            pass
    except OSError as error:
        raise RaySetupError(
            f"no Ray cluster answers at {address} ({error}); start one with "
            "'ray start --head' there, or use --ray local"
        ) from None


def connect(address: str, max_cpus: float) -> Any:
    """Start a local cluster (``local``: at least ``max_cpus`` logical CPUs, so every
    actor is placed; GPUs as Ray finds them) or join the one at ``address``; returns
    the ``ray`` module."""
    if address == LOCAL:
        # Read when Ray is imported: a local cluster's processes bind and talk over
        # loopback (Ray would bind the machine's address: this cluster is for this
        # machine alone).
        os.environ.setdefault("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")
    else:
        _check_reachable(address)
    ray = _import_ray()
    started = time.monotonic()
    try:
        if address == LOCAL:
            cpus = max(os.cpu_count() or 1, math.ceil(max_cpus))
            ray.init(
                num_cpus=cpus,
                object_store_memory=LOCAL_OBJECT_STORE_BYTES,
                include_dashboard=False,
                log_to_driver=True,
                configure_logging=False,
            )
        else:
            ray.init(address=address, log_to_driver=True, configure_logging=False)
    except Exception as error:
        what = "start a local Ray cluster" if address == LOCAL else f"join the cluster {address}"
        hint = ""
        if address != LOCAL and "RAY_AUTH_MODE" not in os.environ:
            hint = (
                " (a cluster with token authentication, as Ray starts them by default, "
                "needs RAY_AUTH_MODE=token here and its token in RAY_AUTH_TOKEN or "
                "~/.ray/auth_token)"
            )
        raise RaySetupError(f"cannot {what}: {type(error).__name__}: {error}{hint}") from None
    resources = ray.cluster_resources()
    log.info(
        "%s Ray cluster at %s in %.1f s: %g CPUs, %g GPUs, %d nodes",
        "started a local" if address == LOCAL else "joined the",
        ray.get_runtime_context().gcs_address,
        time.monotonic() - started,
        resources.get("CPU", 0),
        resources.get("GPU", 0),
        len([node for node in ray.nodes() if node.get("Alive")]),
    )
    return ray


class RayWorker:
    """One worker of the pool, as a Ray actor (threaded: ``signal`` arrives while
    ``run`` works)."""

    def __init__(self, config: WorkerConfig, log_level: int, budget: Any) -> None:
        configure_logging(log_level, config.worker_id)
        # Its job process a fresh interpreter: a fork would copy this process's Ray
        # threads' state without the threads.
        config = dataclasses.replace(config, job_start="spawn")
        if budget is None:
            self.worker = start_worker(config, lambda: True, lambda: None)
        else:
            ray = _import_ray()
            self.worker = start_worker(
                config,
                lambda: bool(ray.get(budget.claim.remote())),
                lambda: ray.get(budget.unclaim.remote()),
            )

    def where(self) -> tuple[int, str]:
        """This actor's process id and node address (for the driver's log)."""
        ray = _import_ray()
        return os.getpid(), ray.util.get_node_ip_address()

    def run(self) -> tuple[int, str]:
        """Work until stopped; the exit status, and the worker's rates for the driver."""
        if self.worker is None:
            return EXIT_SETUP, "could not start"
        code = self.worker.run()
        return code, self.worker.rates.line()

    def signal(self) -> None:
        if self.worker is not None:
            self.worker.signal("SIGTERM")


class _Budget:
    """``--max-jobs`` for the whole pool, as an actor the workers claim jobs from."""

    def __init__(self, jobs: int) -> None:
        self.jobs = jobs

    def claim(self) -> bool:
        if self.jobs <= 0:
            return False
        self.jobs -= 1
        return True

    def unclaim(self) -> None:
        self.jobs += 1


def run_ray(
    config: WorkerConfig,
    concurrency: int,
    address: str,
    sizing: JobResources,
    log_level: int = logging.INFO,
) -> int:
    """Run ``concurrency`` workers as actors on the cluster at ``address`` until they
    stop; the pool's rules are :func:`adworker.pool.run_pool`'s (a worker that dies
    is replaced; a refused token or a worker that cannot start stops the pool).
    Each actor holds ``sizing``. Raises :class:`RaySetupError` when the cluster cannot
    be used."""
    if config.function is not None:
        # A --function that does not import stops the driver here, before any cluster.
        from adworker.worker import make_runner

        try:
            make_runner(config)
        except Exception as error:
            raise RaySetupError(f"cannot start: {type(error).__name__}: {error}") from None
    ray = connect(address, sizing.cpus * concurrency)
    env_vars = {name: os.environ[name] for name in THREAD_VARIABLES if name in os.environ}
    env_vars.update({k: v for k, v in os.environ.items() if k.startswith("AD_")})
    env_vars.pop("AD_TOKEN", None)  # in the config; an actor's environment is shown by Ray
    actor_class = ray.remote(max_concurrency=2, max_restarts=0)(RayWorker)
    budget = (
        ray.remote(num_cpus=0)(_Budget).remote(config.max_jobs)
        if config.max_jobs is not None
        else None
    )
    actors: dict[int, Any] = {}
    refs: dict[Any, tuple[int, str]] = {}
    placed: set[int] = set()
    signals_seen = 0
    signals_sent = 0
    code = EXIT_OK

    def start(slot: int) -> None:
        actor = actor_class.options(**sizing.options(), runtime_env={"env_vars": env_vars}).remote(
            config.for_slot(slot), log_level, budget
        )
        actors[slot] = actor
        refs[actor.run.remote()] = (slot, "run")
        refs[actor.where.remote()] = (slot, "where")

    def on_signal(signum: int, _frame: Any) -> None:
        nonlocal signals_seen
        signals_seen += 1
        log.info("%s: passing it on to %d Ray workers", signal.Signals(signum).name, len(actors))

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    log.info(
        "starting %d Ray workers (%s-0...), each holding %g CPU and %g GPU",
        concurrency,
        config.worker_id,
        sizing.cpus,
        sizing.gpus,
    )
    for slot in range(concurrency):
        start(slot)
    last_pending_report = time.monotonic()
    try:
        while actors:
            while signals_sent < signals_seen:
                signals_sent += 1
                for actor in actors.values():
                    actor.signal.remote()
            ready, _ = ray.wait(list(refs), num_returns=1, timeout=0.5)
            for ref in ready:
                slot, kind = refs.pop(ref)
                name = f"{config.worker_id}-{slot}"
                if kind == "where":
                    try:
                        pid, node = ray.get(ref)
                    except ray.exceptions.RayError:
                        continue  # its run ref says what happened
                    placed.add(slot)
                    log.info("Ray worker %s: pid %d on node %s", name, pid, node)
                    continue
                try:
                    exit_code: int | None
                    exit_code, summary = ray.get(ref)
                    log.info("Ray worker %s stopped (exit %d): %s", name, exit_code, summary)
                except ray.exceptions.RayError as error:
                    exit_code = None
                    reason = str(error).strip().splitlines()[0] if str(error).strip() else ""
                    log.error("Ray worker %s died: %s: %s", name, type(error).__name__, reason)
                actors.pop(slot, None)
                placed.discard(slot)
                action = pool_action(exit_code, signals_seen)
                if action == "stop":
                    code = exit_code if exit_code is not None else EXIT_SETUP
                    signals_seen = max(signals_seen, 1)
                elif action == "replace":
                    log.error("starting another Ray worker in slot %d", slot)
                    time.sleep(1.0)
                    start(slot)
            if len(placed) < len(actors) and (
                time.monotonic() - last_pending_report > PENDING_REPORT_SECONDS
            ):
                last_pending_report = time.monotonic()
                log.warning(
                    "%d of %d Ray workers not started yet: waiting for the cluster's "
                    "resources (%g CPU, %g GPU each; free now: %s) or for their processes",
                    len(actors) - len(placed),
                    len(actors),
                    sizing.cpus,
                    sizing.gpus,
                    ray.available_resources(),
                )
    finally:
        for actor in actors.values():  # only if the driver itself failed
            ray.kill(actor)
        time.sleep(LOG_DRAIN_SECONDS)
        ray.shutdown()
    log.info("all Ray workers stopped")
    return code
