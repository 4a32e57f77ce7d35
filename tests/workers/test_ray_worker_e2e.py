"""``adworker --ray``: workers as actors on a real Ray cluster, against a real adserver.

One ``adworker --ray local`` process (the module's one Ray cluster start) serves a
module server: a stand-up study completes through it, and a Ray worker process killed
mid-job loses nothing (its lease expires and the trial completes on a re-lease). A
second driver joins that cluster by its address, on a server of its own, and gives its
lease back when stopped twice. Without Ray, or with no cluster at the address, adworker
says so and exits 3.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest

from adclient import Client
from adclient.testing.servers import ServerProcess, free_port
from adclient.testing.workers import ADWORKER, PATIENCE, WorkerProcess, wait_for
from tests.workers.robots import running_trial, stand_up_study

pytestmark = [pytest.mark.e2e, pytest.mark.xdist_group("ray")]

JOINING = {"RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0", "RAY_AUTH_MODE": "token"}
"""A driver joining the test cluster: by 127.0.0.1, kept to loopback (Ray would otherwise
put the machine's address in its place), with the token the local cluster was started
with (~/.ray/auth_token: Ray reads it only when told the cluster wants one)."""


def unless_exited(worker: WorkerProcess, condition):
    """A wait's condition that also ends the wait, failing, when the driver has exited."""

    def check():
        value = condition()
        if not value and worker.process.poll() is not None:
            raise AssertionError(f"adworker exited {worker.process.returncode}:\n{worker.log()}")
        return value

    return check


def stop(worker: WorkerProcess) -> None:
    """A driver's teardown: SIGTERM (a second one if it is still busy), so it shuts its
    Ray cluster down itself; a kill only if it will not go."""
    for _ in range(2):
        if worker.process.poll() is not None:
            return
        worker.signal(signal.SIGTERM)
        try:
            worker.wait(timeout=60)
        except subprocess.TimeoutExpired:
            continue
    worker.stop()


@pytest.fixture(scope="module", autouse=True)
def ray_tmpdir() -> Iterator[Path]:
    """Ray's session folders (logs, sockets) for the module's drivers and clusters, in a
    short temporary folder removed afterwards, not in /tmp/ray, where they would stay:
    ``RAY_TMPDIR``, which every process started here inherits."""
    folder = Path(tempfile.mkdtemp(prefix="adray-"))
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("RAY_TMPDIR", str(folder))
        yield folder
    shutil.rmtree(folder, ignore_errors=True)


@pytest.fixture(scope="module")
def cluster(
    tmp_path_factory: pytest.TempPathFactory, ray_tmpdir: Path
) -> Iterator[tuple[ServerProcess, WorkerProcess, str]]:
    """A server (3 s leases) and ``adworker --ray local --concurrency 2`` serving it (half
    a CPU per job: the two hold one of the cluster's CPUs, so a second driver fits);
    the Ray cluster's address."""
    workdir = tmp_path_factory.mktemp("ray")
    server = ServerProcess(
        database_url=f"sqlite:///{workdir / 'studies.db'}",
        workdir=workdir,
        env={"AD_LEASE_SECONDS": "3"},
    ).start()
    driver = WorkerProcess(
        server, workdir, "ray", "--ray", "local", "--concurrency", "2", "--ray-cpus", "0.5"
    )
    try:
        found = wait_for(
            lambda: (
                re.search(r"started a local Ray cluster at (\S+) ", driver.log())
                or driver.process.poll() is not None
            ),
            "the local Ray cluster",
        )
        assert isinstance(found, re.Match), driver.log()
        assert any(ray_tmpdir.glob("ray/session_*")), "Ray's session is not in RAY_TMPDIR"
        yield server, driver, found.group(1)
    finally:
        stop(driver)
        server.stop()


def actor_pids(driver: WorkerProcess) -> dict[str, int]:
    """The driver's Ray workers by name: their process ids, latest first placed."""
    return {
        name: int(pid)
        for name, pid in re.findall(r"Ray worker (\S+): pid (\d+) on node", driver.log())
    }


@pytest.mark.slow
def test_stand_up_study_completes_on_a_local_ray_cluster(cluster) -> None:
    server, driver, _ = cluster
    with Client(server.url) as client:
        study = stand_up_study(client, max_trials=4, learner="fast", train_steps=256)
        final = study.wait(poll=1.0, timeout=PATIENCE)
        assert final.n_complete == 4, [t.message for t in study.trials]
        for trial in study.trials:
            assert trial.worker_id in {"ray-0", "ray-1"}
            assert trial.value is not None and trial.value == trial.metrics["score_mean"]
            assert trial.metrics["train_steps"] == 256
            names = {artifact.name for artifact in client.artifacts(trial)}
            assert names == {"robot.urdf", "robot.png", "curve.json", "replay.json"}
            curve = json.loads(client.get_artifact(trial, "curve.json"))
            assert len(curve["evaluation"]) == 3
    log = driver.log()
    assert "each holding 0.5 CPU and 0 GPU" in log
    assert set(actor_pids(driver)) >= {"ray-0", "ray-1"}
    assert "jobs/min" in log  # the actors' own lines, with their rates, reach the driver


@pytest.mark.slow
def test_killed_ray_worker_process_loses_no_job(cluster) -> None:
    server, driver, _ = cluster
    with Client(server.url) as client:
        # A job of a few seconds, so the kill lands in the middle of it.
        study = stand_up_study(client, max_trials=1, learner="fast", train_steps=32 * 128)

        def holder():
            trial = running_trial(client, study.id, "ray-0") or running_trial(
                client, study.id, "ray-1"
            )
            return trial if trial is not None and trial.worker_id in actor_pids(driver) else None

        trial = wait_for(unless_exited(driver, holder), "a Ray worker's lease")
        pid = actor_pids(driver)[trial.worker_id]
        os.kill(pid, signal.SIGKILL)  # the Ray worker process, as a dying node takes it
        assert client.get_trial(trial).state == "running"  # killed mid-job: nothing told
        wait_for(lambda: f"Ray worker {trial.worker_id} died" in driver.log(), "the death seen")
        final = study.wait(poll=1.0, timeout=PATIENCE)
        assert final.n_complete == 1, driver.log()
        finished = client.get_trial(trial)
        assert finished.state == "complete"
        assert finished.attempts == 2  # the lease expired, and the trial was leased again
    # The dead actor's slot has a new one, in a new process.
    wait_for(lambda: actor_pids(driver)[trial.worker_id] != pid, "a new Ray worker")
    assert driver.process.poll() is None


@pytest.mark.slow
def test_driver_joining_a_cluster_gives_its_lease_back_when_stopped_twice(
    cluster, tmp_path: Path
) -> None:
    _, _, address = cluster
    server = ServerProcess(
        database_url=f"sqlite:///{tmp_path / 'studies.db'}",
        workdir=tmp_path,
        env={"AD_LEASE_SECONDS": "600"},  # only a release can queue it again soon
    ).start()
    leaving = None
    try:
        with Client(server.url) as client:
            study = stand_up_study(client, max_trials=1, learner="fast", train_steps=32 * 512)
            leaving = WorkerProcess(server, tmp_path, "joined", "--ray", address, env=JOINING)
            trial = wait_for(
                unless_exited(leaving, lambda: running_trial(client, study.id, "joined-0")),
                "a lease",
            )
            assert "joined the Ray cluster at" in leaving.log()
            leaving.signal(signal.SIGTERM)
            wait_for(lambda: "finishing the current job" in leaving.log(), "the first SIGTERM")
            leaving.signal(signal.SIGTERM)
            assert leaving.wait() == 0, leaving.log()
            assert "Ray worker joined-0 stopped (exit 0): 0 jobs" in leaving.log()
            queued = client.get_trial(trial)
            assert queued.state == "queued" and queued.attempts == 0, leaving.log()
    finally:
        if leaving is not None:
            leaving.stop()
        server.stop()


def test_ray_without_ray_or_a_cluster_exits_3_saying_why(tmp_path: Path) -> None:
    # Neither the SDK nor the worker's command line imports Ray.
    light = "import sys, adclient.client, adworker.cli; print('ray' in sys.modules)"
    assert (
        subprocess.run(
            [sys.executable, "-c", light], capture_output=True, text=True, check=True
        ).stdout.strip()
        == "False"
    )

    no_ray = (
        "import sys; sys.modules['ray'] = None; from adworker.cli import main; "
        "sys.argv = ['adworker', '--ray', 'local']; main()"
    )
    missing = subprocess.run([sys.executable, "-c", no_ray], capture_output=True, text=True)
    assert missing.returncode == 3, missing.stderr
    assert "--ray needs Ray, which is not installed here" in missing.stderr
    assert "activedesign[ray]" in missing.stderr
    assert "Traceback" not in missing.stderr

    nobody = f"127.0.0.1:{free_port()}"
    unreachable = subprocess.run(
        [str(ADWORKER), "--ray", nobody], capture_output=True, text=True, env=os.environ
    )
    assert unreachable.returncode == 3, unreachable.stderr
    assert f"no Ray cluster answers at {nobody}" in unreachable.stderr
    bad = subprocess.run([str(ADWORKER), "--ray", "head-node"], capture_output=True, text=True)
    assert bad.returncode == 3 and "is not a cluster address" in bad.stderr
    typo = [str(ADWORKER), "--ray", "local", "--function", "no_such_module:score", "--task", "t"]
    unimportable = subprocess.run(typo, capture_output=True, text=True, cwd=tmp_path)
    assert unimportable.returncode == 3, unimportable.stderr  # before any cluster starts
    assert "cannot start: " in unimportable.stderr and "no_such_module" in unimportable.stderr
    assert "Ray cluster" not in unimportable.stderr
