"""The learner's torch device is an ``adworker`` option (``--learner-device``, env
``AD_LEARNER_DEVICE``): cpu trains stable-baselines3 jobs in a pool of real worker
processes; cuda where torch has no GPU stops the worker at start, saying why."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from adclient import Client
from adclient.testing.servers import ServerProcess, free_port
from adclient.testing.workers import WorkerProcess, run_adworker
from tests.workers.robots import example_study

pytestmark = pytest.mark.e2e


def test_a_pool_trains_on_the_cpu_it_is_given(server: ServerProcess, tmp_path: Path) -> None:
    body = example_study("stand-up").model_dump(mode="json")
    body["max_trials"] = 2
    body["task"].update(learner="ppo", train_steps=64)
    with Client(server.url) as client:
        study = client.create_study(body)
        worker = WorkerProcess(
            server, tmp_path, "cpu-pool", "--concurrency", "2", "--max-jobs", "2",
            env={"AD_LEARNER_DEVICE": "cpu"},
        )  # fmt: skip
        try:
            assert worker.wait() == 0, worker.log()
        finally:
            worker.stop()
        trials = client.trials(study.id)
    assert [trial.state for trial in trials] == ["complete", "complete"], worker.log()
    assert all(trial.metrics["train_steps"] == 64 for trial in trials)


@pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has a CUDA GPU")
@pytest.mark.parametrize("how", ["option", "environment"])
def test_a_worker_asked_for_cuda_without_a_gpu_exits_saying_why(how: str) -> None:
    server = f"http://127.0.0.1:{free_port()}"  # never reached: the worker stops first
    args, env = ["--learner-device", "cuda"], {}
    if how == "environment":
        args, env = [], {"AD_LEARNER_DEVICE": "cuda"}
    done = run_adworker("--server", server, *args, **env)  # forked: torch is preloaded
    assert done.returncode == 3, done.stderr
    said = done.stderr
    assert "Traceback" not in said + done.stdout
    assert said.startswith("adworker: --learner-device cuda cannot be used: ")
    assert "--learner-device cpu" in said
