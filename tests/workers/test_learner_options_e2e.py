"""A learner's options by whitelist (issue 58): what a study's
``task.options.learner_kwargs`` may set is what its learner's options model declares,
each option bounded and their cost together bounded for the study's steps; a real
adserver with auth on refuses anything else from a plain ``user`` token with a 422
naming it, storing nothing. A study stored before the check (its lax options written
straight into the database) still loads, and a real adworker fails its job naming
the option."""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from adclient import Client
from adclient.plugins import catalogue
from adclient.schemas import TrialState
from adclient.testing.servers import ServerProcess, make_token
from adclient.testing.workers import PATIENCE, WorkerProcess
from tests.failing_proposals import update_study
from tests.workers.robots import example_study

pytestmark = pytest.mark.e2e

DOCS = Path(__file__).resolve().parents[2] / "docs"


@pytest.fixture(scope="module")
def secured(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    work = tmp_path_factory.mktemp("learner-options")
    server = ServerProcess(
        database_url=f"sqlite:///{work / 'studies.db'}", workdir=work, env={"AD_AUTH": "true"}
    )
    yield server.start()
    server.stop()


@pytest.fixture(scope="module")
def user(secured: ServerProcess) -> Iterator[httpx.Client]:
    token = make_token(secured, "user", name="someone")
    headers = {"Authorization": f"Bearer {token}", "X-Activedesign-Client": "test"}
    with httpx.Client(base_url=secured.url, headers=headers, timeout=60, verify=False) as http:
        yield http


def study(learner: str, learner_kwargs: dict[str, Any], **task: Any) -> dict[str, Any]:
    body = example_study("stand-up").model_dump(mode="json", exclude_unset=True)
    body["max_trials"] = 1
    body["proposer"] = {"name": "random", "seed": 0}
    body["task"].update({"learner": learner, "options": {"learner_kwargs": learner_kwargs}, **task})
    return body


@pytest.mark.parametrize(
    ("learner", "kwargs", "task", "named"),
    [
        # the study: a 200-step job that held a worker for 11 minutes
        ("ddpg", {"gradient_steps": 1_000_000_000}, {"train_steps": 200}, ["gradient_steps"]),
        (
            "td3",
            {"gradient_steps": 1000},
            {"train_steps": 100_000},
            ["100,000,000 gradient updates", "gradient_steps 1000", "limit of 10,000,000"],
        ),
        (
            "ppo",
            {"n_epochs": 100, "batch_size": 2, "n_steps": 16_384},
            {"train_steps": 1_000_000},
            ["gradient updates", "n_epochs 100", "batch_size 2"],
        ),
        ("sac", {"tensorboard_log": "/tmp/sb3-logs"}, {}, ["tensorboard_log", "unknown option"]),
        ("ddpg", {"policy_kwargs": {"net_arch": [4096]}}, {}, ["policy_kwargs", "net_arch"]),
        ("sac", {"device": "cuda"}, {}, ["learner_kwargs.device", "learning_rate, gamma"]),
        ("ppo", {"net_arch": [4096, 4096]}, {}, ["learner_kwargs.net_arch.0", "256"]),
        # issue 59's batch of worlds: each a whole simulator, 32 at most
        ("ppo", {"n_envs": 33}, {}, ["learner_kwargs.n_envs", "32"]),
        ("td3", {"net_arch": [256, 256, 256]}, {}, ["more than the limit of 65,536"]),
        ("ddpg", {"buffer_size": 10**9}, {}, ["learner_kwargs.buffer_size"]),
        ("ddpg", {"action_noise": {"kind": "ou", "sigma": 0.2, "size": 9}}, {}, ["size"]),
        ("ppo", {"action_noise": {"kind": "normal"}}, {}, ["action_noise", "unknown option"]),
        ("sac", {"ent_coef": "auto_0.1"}, {}, ["learner_kwargs.ent_coef"]),
    ],
)
def test_learner_options_outside_the_whitelist_are_refused_naming_them(
    user: httpx.Client, learner: str, kwargs: dict[str, Any], task: dict[str, Any], named: list[str]
) -> None:
    before = user.get("/api/v1/studies").json()
    answer = user.post("/api/v1/studies", json=study(learner, kwargs, **task))
    assert answer.status_code == 422, answer.text
    detail = answer.json()["detail"]
    for text in named:
        assert text in detail, (text, detail)
    assert user.get("/api/v1/studies").json() == before, "a refused study was stored"


@pytest.mark.parametrize(
    ("learner", "kwargs"),
    [
        ("ddpg", {"learning_rate": 3e-4, "action_noise": {"kind": "normal", "sigma": 0.2}}),
        ("sac", {"ent_coef": "auto", "gradient_steps": 4, "train_freq": 2, "net_arch": [32]}),
        ("td3", {"policy_delay": 3, "batch_size": 256, "buffer_size": 20_000}),
        ("ppo", {"gamma": 0.5, "n_epochs": 2, "net_arch": [128, 128]}),
    ],
)
def test_options_within_the_whitelist_are_accepted_and_stored_as_given(
    user: httpx.Client, learner: str, kwargs: dict[str, Any]
) -> None:
    answer = user.post("/api/v1/studies", json=study(learner, kwargs, train_steps=2000))
    assert answer.status_code == 201, answer.text
    assert answer.json()["task"]["options"] == {"learner_kwargs": kwargs}


def test_each_built_in_learner_option_is_documented() -> None:
    """docs/worker.md's table of learner options names every option of every built-in
    learner's options model."""
    doc = (DOCS / "worker.md").read_text(encoding="utf-8")
    table = doc.split("<!-- learner options -->", 1)[1].split("\n\n", 1)[0]
    listed = set(re.findall(r"`([a-z_]+)`", table))
    for name, spec in catalogue().learners.items():
        if spec.options is not None:
            missing = set(spec.options.model_fields) - listed
            assert not missing, (name, missing)


@pytest.mark.slow
def test_a_study_stored_with_options_now_refused_still_loads_and_its_job_fails_naming_them(
    tmp_path: Path, new_sqlite_url
) -> None:
    server = ServerProcess(
        database_url=new_sqlite_url(), workdir=tmp_path, env={"AD_AUTH": "true"}
    ).start()
    try:
        with Client(server.url, make_token(server, "user", name="someone")) as client:
            stored = client.create_study(study("ddpg", {}, train_steps=64))
            lax = {"learner_kwargs": {"policy_kwargs": {"net_arch": [8]}, "batch_size": 4096}}
            task = {**stored.info.task.model_dump(mode="json"), "options": lax}
            update_study(server.database_url, stored.id, task=task)
            assert stored.id in [row.id for row in client.studies()]  # it loads
            token = make_token(server, "worker", name="careful")
            worker = WorkerProcess(server, tmp_path, "careful", "--token", token, "--max-jobs", "1")
            try:
                assert worker.wait(PATIENCE) == 0, worker.log()
            finally:
                worker.stop()
            [trial] = client.trials(stored.id)
    finally:
        server.stop()
    assert trial.state == TrialState.failed, worker.log()
    message = trial.message or ""
    assert "task.options.learner_kwargs.policy_kwargs: unknown option" in message, message
    assert "task.options.learner_kwargs.batch_size" in message, message
    assert "refused by this worker" in message
