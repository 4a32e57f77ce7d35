"""``adworker``: evaluate designs for an activedesign server until stopped.

    adworker --server http://127.0.0.1:8000 --token $AD_TOKEN --concurrency 2

    adworker --function my_sim:score --task my-sim      # a plain callable instead
    adworker tasks                                      # what this worker can run
    adworker --ray local --concurrency 8                # workers as Ray actors
    adworker --ray head-node:6379 --concurrency 64      # on a running Ray cluster

Each worker process leases a job of a task it has, trains and evaluates the design
in PyBullet (or calls the function), and reports the score with its metrics and
artifacts (URDF, picture, curve). Each job runs in a process of its own under a time
and a memory limit (``--job-seconds``, ``--job-step-seconds``, ``--job-memory-mb``): one
past them is stopped and its trial failed, naming the limit. SIGTERM or Ctrl-C: finish
the current job within ``--stop-grace`` seconds and exit; a second one, or the grace
run out: abandon it, give its lease back and exit now. Exit status 0 when stopped, 2 on a usage
error, 3 when the worker could not start (a function that does not import,
``--learner-device cuda`` without a GPU), 4 when the server refused the token. An https
server with a private or self-signed certificate needs ``--ca-bundle`` (env
``AD_CA_BUNDLE``).
"""

from __future__ import annotations

import logging
import os
import sys
from enum import StrEnum
from pathlib import Path

import typer

from adclient.cli.common import CA_BUNDLE_OPTION
from adclient.devices import LEARNER_DEVICE_VARIABLE, device_problem
from adworker.jobprocess import JobLimits, setup_problem
from adworker.pool import run_pool
from adworker.worker import (
    EXIT_OK,
    EXIT_SETUP,
    Worker,
    WorkerConfig,
    configure_logging,
    default_worker_id,
)


class Device(StrEnum):
    """Where learners train (``--learner-device``)."""

    cpu = "cpu"
    cuda = "cuda"


app = typer.Typer(
    name="adworker",
    help="Simulation worker for an activedesign server.",
    add_completion=False,
    pretty_exceptions_enable=False,
)


@app.callback(invoke_without_command=True)
def run(
    ctx: typer.Context,
    server: str = typer.Option(
        "http://127.0.0.1:8000", "--server", envvar="AD_SERVER_URL", help="Server base URL."
    ),
    token: str | None = typer.Option(
        None, "--token", envvar="AD_TOKEN", help="A worker (or admin) bearer token."
    ),
    ca_bundle: Path | None = CA_BUNDLE_OPTION,
    concurrency: int = typer.Option(
        1,
        "--concurrency",
        min=1,
        max=256,
        help="Jobs at once, each in its own process (with --ray: its own Ray actor).",
    ),
    ray: str | None = typer.Option(
        None,
        "--ray",
        envvar="AD_RAY_ADDRESS",
        help="Run the workers as actors on a Ray cluster: 'local' starts one on this machine; "
        "HOST:PORT (its GCS), 'auto' or ray://HOST:PORT joins a running one.",
    ),
    ray_cpus: float | None = typer.Option(
        None, "--ray-cpus", min=0.0, help="With --ray: CPUs each job holds (default 1)."
    ),
    ray_gpus: float | None = typer.Option(
        None,
        "--ray-gpus",
        min=0.0,
        help="With --ray: GPUs each job holds (default 1 with --learner-device cuda, else 0; "
        "a fraction shares a GPU).",
    ),
    poll: float = typer.Option(
        2.0, "--poll", min=0.05, help="Seconds between lease attempts when there is no work."
    ),
    max_jobs: int | None = typer.Option(
        None, "--max-jobs", min=1, help="Exit after this many jobs (all processes together)."
    ),
    worker_id: str | None = typer.Option(
        None, "--worker-id", help="Name shown on the server (default: host-pid)."
    ),
    idle_exit: float | None = typer.Option(
        None, "--idle-exit", min=0.0, help="Exit after this many seconds without work."
    ),
    workdir: Path | None = typer.Option(
        None, "--workdir", help="Where jobs write their files (default: a temporary folder)."
    ),
    keep_files: bool = typer.Option(
        False, "--keep-files", help="Keep each job's URDF, picture and curve in the workdir."
    ),
    render: bool = typer.Option(True, "--render/--no-render", help="Upload a picture."),
    function: str | None = typer.Option(
        None,
        "--function",
        help="Score each job with this callable (module:attr) instead of an installed task.",
    ),
    task: str | None = typer.Option(
        None, "--task", help="With --function: the task name whose studies it serves."
    ),
    app_dir: Path = typer.Option(
        Path("."), "--app-dir", help="Where --function's module is imported from."
    ),
    learner_device: Device = typer.Option(
        Device.cpu,
        "--learner-device",
        envvar=LEARNER_DEVICE_VARIABLE,
        help="The torch device learners train on: cpu, or cuda (a GPU, checked at start).",
    ),
    job_seconds: float = typer.Option(
        3600.0,
        "--job-seconds",
        envvar="AD_JOB_SECONDS",
        min=1.0,
        help="The most seconds a job may run; past it the job is stopped and its trial failed.",
    ),
    job_step_seconds: float = typer.Option(
        0.05,
        "--job-step-seconds",
        envvar="AD_JOB_STEP_SECONDS",
        min=0.0,
        help="A job whose study sets train_steps gets at most 60 s plus this for each step "
        "it trains and evaluates (less than --job-seconds).",
    ),
    job_memory_mb: int = typer.Option(
        2048,
        "--job-memory-mb",
        envvar="AD_JOB_MEMORY_MB",
        min=0,
        help="The most memory (MB) a job may allocate in its process; 0: no limit.",
    ),
    stop_grace: float = typer.Option(
        25.0,
        "--stop-grace",
        envvar="AD_STOP_GRACE",
        min=0.0,
        help="Seconds the current job gets to finish after SIGTERM; then it is abandoned.",
    ),
    log_level: str = typer.Option("info", "--log-level", envvar="AD_LOG_LEVEL"),
    batch_designs: int = typer.Option(
        0,
        "--batch-designs",
        min=0,
        help="GPU mode (the gpu extra): lease up to this many stand-up trials on MuJoCo and "
        "train those of one study and tree in one MuJoCo Warp batch (adworker.gpu); 0: off.",
    ),
    worlds_per_design: int = typer.Option(
        16, "--worlds-per-design", min=1, help="With --batch-designs: worlds per design."
    ),
) -> None:
    """Lease and evaluate jobs until stopped."""
    if ctx.invoked_subcommand is not None:
        return
    if (function is None) != (task is None):
        raise typer.BadParameter("--function and --task go together", param_hint="--task")
    # One BLAS/torch thread per process: N processes share the cores.
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    os.environ.setdefault("MKL_NUM_THREADS", "1")
    _threads_of_imported_torch()
    level = logging.getLevelNamesMapping().get(log_level.upper())
    if level is None:
        raise typer.BadParameter(f"unknown log level {log_level!r}", param_hint="--log-level")
    problem = device_problem(learner_device.value)
    if problem is not None:
        typer.echo(
            f"adworker: --learner-device {learner_device.value} cannot be used: {problem}; "
            f"train on the CPU with --learner-device cpu ({LEARNER_DEVICE_VARIABLE}=cpu)",
            err=True,
        )
        raise typer.Exit(EXIT_SETUP)
    os.environ[LEARNER_DEVICE_VARIABLE] = learner_device.value  # the learners read it, pool's too
    base_id = worker_id or default_worker_id()
    config = WorkerConfig(
        server=server,
        token=token,
        worker_id=base_id,
        poll=poll,
        max_jobs=max_jobs,
        idle_exit=idle_exit,
        workdir=workdir,
        keep_files=keep_files,
        render=render,
        ca_bundle=ca_bundle.resolve() if ca_bundle is not None else None,
        function=function,
        task=task,
        app_dir=app_dir.resolve(),
        limits=JobLimits(
            seconds=job_seconds,
            step_seconds=job_step_seconds,
            memory_mb=job_memory_mb or None,
        ),
        stop_grace=stop_grace,
    )
    configure_logging(level, base_id)
    if batch_designs:
        raise typer.Exit(_run_gpu_batches(config, batch_designs, worlds_per_design))
    if ray is not None:
        raise typer.Exit(
            _run_on_ray(config, concurrency, ray, learner_device.value, ray_cpus, ray_gpus, level)
        )
    if ray_cpus is not None or ray_gpus is not None:
        raise typer.BadParameter("--ray-cpus and --ray-gpus go with --ray", param_hint="--ray")
    if concurrency == 1:
        try:
            worker = Worker(config)
        except Exception as error:
            typer.echo(f"adworker: cannot start: {setup_problem(error)}", err=True)
            raise typer.Exit(EXIT_SETUP) from None
        worker.install_signal_handlers()
        code = worker.run()
    else:
        code = run_pool(config, concurrency, level)
    raise typer.Exit(code)


def _threads_of_imported_torch() -> None:
    """torch takes its thread count from OMP_NUM_THREADS when it is first imported; one
    imported before this process set it (a process forked from preloaded imports) is
    given it now. A worker that has not imported torch imports it later, and reads it."""
    torch = sys.modules.get("torch")
    threads = os.environ["OMP_NUM_THREADS"]
    if torch is not None and threads.isdigit() and int(threads) > 0:
        torch.set_num_threads(int(threads))


def _run_gpu_batches(config: WorkerConfig, batch_designs: int, worlds_per_design: int) -> int:
    """``--batch-designs``: the GPU mode (adworker.gpu.jobs, the one path that imports
    MuJoCo Warp)."""
    import tempfile

    from adclient import Client
    from adworker.gpu.jobs import run_batches

    client = Client(
        config.server,
        config.token,
        verify=str(config.ca_bundle) if config.ca_bundle is not None else True,
    )
    with tempfile.TemporaryDirectory(prefix="adworker-gpu-") as folder:
        told = run_batches(
            client,
            config.worker_id,
            Path(folder),
            batch_designs=batch_designs,
            worlds_per_design=worlds_per_design,
            max_jobs=config.max_jobs,
            idle_exit=config.idle_exit,
            poll=config.poll,
        )
    logging.getLogger(__name__).info("told %d trials (--batch-designs)", told)
    return EXIT_OK


def _run_on_ray(
    config: WorkerConfig,
    concurrency: int,
    address: str,
    learner_device: str,
    cpus: float | None,
    gpus: float | None,
    level: int,
) -> int:
    """``--ray``: the pool on a Ray cluster (adworker.raypool, the one module that
    imports Ray); a cluster that cannot be used is exit status 3 with its reason."""
    from adworker.raypool import RaySetupError, job_resources, run_ray

    sizing = job_resources(
        learner_device, function=config.function is not None, cpus=cpus, gpus=gpus
    )
    try:
        return run_ray(config, concurrency, address, sizing, level)
    except RaySetupError as error:
        typer.echo(f"adworker: {error}", err=True)
        return EXIT_SETUP


@app.command("tasks")
def list_tasks() -> None:
    """List the installed tasks and learners, and any that does not load here."""
    from adclient.plugins import catalogue
    from adworker.runner import factory_problem

    for line in catalogue().describe(factory_problem):
        typer.echo(line)


def main() -> None:
    app()


if __name__ == "__main__":
    main()
