"""The GPU worker mode (``adworker --batch-designs K``, issue 59): lease up to K trials, one
lease after another (the lease API leases one a call), group those of one study and one
tree, train every group's designs together in one MuJoCo Warp batch (PPO, one policy per
design: :mod:`adworker.gpu.ppo`), and tell each trial its design's score.

What it leases: stand-up on MuJoCo with a PPO learner (``ppo`` or ``ppo-batch``); a
leased trial of another simulator is given back at once for a CPU worker. Each trial's
budget is its study's ``task.train_steps`` (else :data:`DEFAULT_STEPS`) env steps, its
seed the study's ``task.seed``. While a batch trains, a thread extends every trial's
lease. A group the batch refuses (designs of other trees, a field Warp holds once)
fails its trials with the reason.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from adclient import Client
from adclient.schemas import Job
from adworker.evaluate import task_options
from adworker.job_robots import job_robot
from adworker.tasks.base import RobotEnv

log = logging.getLogger(__name__)

LEARNERS = ("ppo", "ppo-batch")
"""The learners whose trials this mode trains (with its own PPO on the batch)."""
DEFAULT_STEPS = 20_000
MAX_BATCH_DESIGNS = 1024
HEARTBEAT_EVERY = 10.0


def _tree_key(job: Job, env: RobotEnv) -> tuple[Any, ...]:
    robot = env.robot
    return (job.study_id, tuple(robot.link_names), tuple(j.name for j in robot.joints))


def _env(job: Job, folder: Path) -> RobotEnv:
    from adclient.plugins import catalogue

    design, urdf = job_robot(job)
    path = folder / f"trial-{job.trial_id}.urdf"
    path.write_text(urdf)
    spec = catalogue().task(job.task.name)
    env = spec.load_factory()(
        design=design, urdf_path=path, options=task_options(job.task), simulator="mujoco"
    )
    assert isinstance(env, RobotEnv)
    return env


class _Heartbeats:
    """Extends the leases of the trials being trained until stopped."""

    def __init__(self, client: Client, worker_id: str, jobs: Sequence[Job]) -> None:
        self._stop = threading.Event()
        self._thread = threading.Thread(
            target=self._run, args=(client, worker_id, list(jobs)), daemon=True
        )

    def _run(self, client: Client, worker_id: str, jobs: list[Job]) -> None:
        while not self._stop.wait(HEARTBEAT_EVERY):
            for job in jobs:
                try:
                    client.heartbeat(job.trial_id, worker_id)
                except Exception as exc:  # a lost lease: its tell will be refused
                    log.warning("trial %d: heartbeat failed (%s)", job.trial_id, exc)

    def __enter__(self) -> _Heartbeats:
        self._thread.start()
        return self

    def __exit__(self, *_: object) -> None:
        self._stop.set()
        self._thread.join()


def train_group(
    client: Client,
    worker_id: str,
    jobs: Sequence[Job],
    envs: Sequence[RobotEnv],
    *,
    worlds_per_design: int,
    device: str | None,
) -> int:
    """Train one group's designs in one batch and tell each trial; the trials told."""
    from adworker.gpu.ppo import GpuPPOOptions, train
    from adworker.gpu.warp_batch import WarpBatch

    task = jobs[0].task
    try:
        batch = WarpBatch(envs, worlds_per_design, device=device)
        options = GpuPPOOptions(
            steps=task.train_steps or DEFAULT_STEPS, seed=task.seed, unroll=16, epochs=8
        )
        with _Heartbeats(client, worker_id, jobs):
            _, result = train(batch, options)
    except ValueError as exc:
        for job in jobs:
            client.tell(job.trial_id, state="failed", message=str(exc), worker_id=worker_id)
        return len(jobs)
    for job, score in zip(jobs, result.scores, strict=True):
        client.tell(job.trial_id, value=float(score), worker_id=worker_id)
    log.info(
        "trained %d designs together, %d env steps each: scores %s",
        len(jobs),
        result.env_steps,
        [round(s, 4) for s in result.scores],
    )
    return len(jobs)


def run_batches(
    client: Client,
    worker_id: str,
    workdir: Path,
    *,
    batch_designs: int,
    worlds_per_design: int,
    device: str | None = None,
    max_jobs: int | None = None,
    idle_exit: float | None = None,
    poll: float = 1.0,
) -> int:
    """Lease, batch and train until out of jobs (``max_jobs``) or idle (``idle_exit``);
    the trials told."""
    if not 1 <= batch_designs <= MAX_BATCH_DESIGNS:
        raise ValueError(f"--batch-designs must be 1 to {MAX_BATCH_DESIGNS}")
    told = 0
    idle_since = time.monotonic()
    while max_jobs is None or told < max_jobs:
        leased: list[Job] = []
        want = batch_designs if max_jobs is None else min(batch_designs, max_jobs - told)
        while len(leased) < want:
            job = client.lease(worker_id, tasks=["stand-up"], learners=list(LEARNERS))
            if job is None:
                break
            if job.task.simulator != "mujoco":
                client.release(job.trial_id, worker_id)
                log.info("trial %d is on %s: given back", job.trial_id, job.task.simulator)
                continue
            leased.append(job)
        if not leased:
            if idle_exit is not None and time.monotonic() - idle_since >= idle_exit:
                break
            time.sleep(poll)
            continue
        groups: dict[tuple[Any, ...], list[tuple[Job, RobotEnv]]] = defaultdict(list)
        for job in leased:
            try:
                env = _env(job, workdir)
            except Exception as exc:
                client.tell(job.trial_id, state="failed", message=str(exc), worker_id=worker_id)
                told += 1
                continue
            groups[_tree_key(job, env)].append((job, env))
        for members in groups.values():
            jobs = [job for job, _ in members]
            envs = [env for _, env in members]
            try:
                told += train_group(
                    client,
                    worker_id,
                    jobs,
                    envs,
                    worlds_per_design=worlds_per_design,
                    device=device,
                )
            finally:
                for env in envs:
                    env.close()
        idle_since = time.monotonic()
    return told
