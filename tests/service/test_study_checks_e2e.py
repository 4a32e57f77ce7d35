"""A new study is checked whole at creation, through a real server: each mistake that
used to be accepted (and fail every trial in the worker), answer 500, or be silently
ignored is a 422 naming the field, and nothing is stored. A study stored before these
checks with options its proposer cannot use answers 409 when asked, never 500, and
does not hold up the workers' leases."""

from __future__ import annotations

import copy
import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
import sqlalchemy as sa
import yaml

from adclient.schemas import TaskConfig
from adclient.testing.servers import ServerProcess

pytestmark = [pytest.mark.e2e, pytest.mark.xdist_group("study-checks")]
"""One xdist worker runs the module: the tests on ``shared_server`` share its two servers."""

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
BOX = {
    "name": "box",
    "space": {
        "type": "box",
        "params": [{"name": "x", "low": -1.0, "high": 1.0}, {"name": "y", "low": 0, "high": 5}],
    },
}


def example(name: str) -> dict[str, Any]:
    return yaml.safe_load((EXAMPLES / f"{name}.yaml").read_text())


def changed(body: dict[str, Any], path: str, value: Any) -> dict[str, Any]:
    """A copy of ``body`` with the value at a dotted ``path`` set."""
    body = copy.deepcopy(body)
    *parents, last = path.split(".")
    target = body
    for key in parents:
        target = target.setdefault(key, {})
    target[last] = value
    return body


@pytest.fixture
def http(shared_server: ServerProcess) -> Iterator[httpx.Client]:
    """The module's server: a test counts the studies before and after its own."""
    with httpx.Client(base_url=shared_server.url, timeout=60, verify=False) as client:
        yield client


@pytest.fixture
def own_http(live_server: ServerProcess) -> Iterator[httpx.Client]:
    """A server of the test's own, for a test that leases (any study's job) or stops it."""
    with httpx.Client(base_url=live_server.url, timeout=60, verify=False) as client:
        yield client


def study_count(http: httpx.Client) -> int:
    return len(http.get("/api/v1/studies").json())


def assert_refused(http: httpx.Client, body: dict[str, Any] | str, *named: str) -> None:
    """422 in the ErrorBody format, a problem naming each of ``named`` (the field's path
    first), and no study stored."""
    before = study_count(http)
    if isinstance(body, str):  # raw JSON: NaN and Infinity tokens survive
        response = http.post(
            "/api/v1/studies", content=body, headers={"Content-Type": "application/json"}
        )
    else:
        response = http.post("/api/v1/studies", json=body)
    assert response.status_code == 422, response.text
    answer = response.json()
    assert answer["error"] == "invalid"
    assert isinstance(answer["problems"], list) and answer["problems"], answer
    assert answer["detail"] == "; ".join(answer["problems"])
    text = " | ".join(answer["problems"])
    for fragment in named:
        assert fragment in text, (fragment, answer["problems"])
    assert study_count(http) == before


def assert_created(http: httpx.Client, body: dict[str, Any]) -> dict[str, Any]:
    before = study_count(http)
    response = http.post("/api/v1/studies", json=body)
    assert response.status_code == 201, response.text
    assert study_count(http) == before + 1
    return response.json()


def test_task_and_learner_must_be_built_in_and_tasks_need_a_design_space(
    http: httpx.Client,
) -> None:
    stand_up = example("stand-up")
    assert_refused(http, changed(stand_up, "task.name", "stand_up"), "task.name", "stand-up")
    assert_refused(http, changed(stand_up, "task.learner", "dqn"), "task.learner", "ddpg")
    managed_box = BOX | {"task": {"name": "lift-highest"}, "max_trials": 5}
    assert_refused(http, managed_box, "needs a design space", "'box'")
    assert_created(http, stand_up)


def test_an_external_task_is_left_to_its_own_workers(own_http: httpx.Client) -> None:
    """Said explicitly, a task of one's own workers may have any name, learner, options
    and space; the lease hands it to whoever asks."""
    task = {"name": "my-sim", "learner": "mine", "options": {"gravity": 3.7}, "external": True}
    study = assert_created(own_http, BOX | {"task": task, "max_trials": 2})
    job = own_http.post("/api/v1/jobs/lease", json={"worker_id": "own"})
    assert job.status_code == 200, job.text
    assert job.json()["study_id"] == study["id"]
    # the job leaves out the task's defaults (docs/worker.md, workers older than the server)
    assert job.json()["task"] == task and study["task"]["external"] is True
    assert TaskConfig.model_validate(job.json()["task"]) == TaskConfig.model_validate(study["task"])


@pytest.mark.parametrize(
    ("options", "named"),
    [
        ({"episode_step": 10}, ["task.options: episode_step: unknown option", "frame_skip"]),
        ({"frame_skip": "twelve"}, ["task.options: frame_skip: Input should be a valid integer"]),
        ({"frame_skip": 0}, ["task.options: frame_skip:"]),
        ({"time_step": -0.01}, ["task.options: time_step:"]),
        ({"distal_link": "c"}, ["task.options: distal_link: unknown option of task 'stand-up'"]),
        ({"feet_links": "a,c"}, ["task.options: feet_links:"]),
        ({"learner_kwargs": {"learning_rate": 0.01}}, ["learner_kwargs: learner 'fast'"]),
        ({"lifted_link": "body"}, ["link 'body' (task.options.lifted_link)"]),
    ],
)
def test_task_options_are_checked(
    http: httpx.Client, options: dict[str, Any], named: list[str]
) -> None:
    assert_refused(http, changed(example("stand-up"), "task.options", options), *named)


def test_task_options_the_worker_understands_are_accepted(http: httpx.Client) -> None:
    body = changed(example("stand-up"), "task.learner", "ddpg")
    options = {
        "frame_skip": 6,
        "time_step": 1 / 240,
        "lifted_link": "b",
        "feet_links": ["a", "c"],
        "learner_kwargs": {"learning_rate": 3e-4},
    }
    study = assert_created(http, changed(body, "task.options", options))
    assert study["task"]["options"] == options  # stored as given, no defaults added


def test_a_design_without_the_links_a_task_looks_up_is_refused(http: httpx.Client) -> None:
    body = example("stand-up")
    body["space"]["instances"][1]["name"] = "body"
    body["space"]["structures"] = [[["a", "body"], ["body", "c"]]]
    assert_refused(http, body, "looks up link 'b'", "lifted_link")
    assert_created(http, changed(body, "task.options", {"lifted_link": "body"}))


@pytest.mark.parametrize(
    ("name", "options", "named"),
    [
        ("tpe", {"n_startup_trials": "ten"}, "proposer.options.n_startup_trials: Input should"),
        ("tpe", {"n_warmup": 5}, "proposer.options.n_warmup: unknown option of tpe"),
        ("nelder-mead", {"initial_step": "big"}, "proposer.options.initial_step: Input should"),
        ("nelder-mead", {"initial_step": 2.0}, "proposer.options.initial_step: Input should"),
        ("qei", {"num_restarts": "many"}, "proposer.options.num_restarts: Input should"),
        ("qei", {"noise": "loud"}, "proposer.options.noise: Input should be 'inferred'"),
        ("qei", {"kernel": "matern52"}, "proposer.options.kernel: Input should be 'rbf'"),
        ("qei", {"raw_samples": 4, "num_restarts": 8}, "raw_samples (4) must be >= num_restarts"),
        ("qei", {"warm_start": "sometimes"}, "proposer.options.warm_start: Input should"),
        ("random", {"seed": 1}, "proposer.options.seed: unknown option of random"),
    ],
)
def test_proposer_options_are_checked(
    http: httpx.Client, name: str, options: dict[str, Any], named: str
) -> None:
    assert_refused(http, BOX | {"proposer": {"name": name, "options": options}}, named)


def test_declared_proposer_options_are_accepted_and_used(http: httpx.Client) -> None:
    for name, options in [
        ("tpe", {"n_startup_trials": 2, "multivariate": False}),
        ("nelder-mead", {"initial_step": 0.25, "adaptive": True}),
        ("qei", {"noise": "fixed", "kernel": "matern", "num_restarts": 2, "raw_samples": 32}),
    ]:
        body = BOX | {"proposer": {"name": name, "options": options, "n_initial": 2}}
        study = assert_created(http, body)
        for _ in range(3):
            asked = http.post(f"/api/v1/studies/{study['id']}/ask", json={"count": 1})
            assert asked.status_code == 200, asked.text
            (trial,) = asked.json()["trials"]
            told = http.post(
                f"/api/v1/trials/{trial['id']}/tell", json={"value": -(trial["params"]["x"] ** 2)}
            )
            assert told.status_code == 200, told.text
        last = asked.json()["trials"][0]["info"]
        assert last["method"] in {"tpe", "nelder-mead", "LogEI"}, (name, last)


def test_unknown_proposer_has_a_problems_list(http: httpx.Client) -> None:
    assert_refused(http, BOX | {"proposer": {"name": "cmaes"}}, "proposer.name: unknown proposer")


def test_numbers_must_be_finite(http: httpx.Client) -> None:
    multi = example("multi-structure")
    for value in ("Infinity", "NaN", "-Infinity"):  # JSON tokens Python's parser accepts
        raw = json.dumps(changed(multi, "space.fusion_margin", 0.0)).replace(
            '"fusion_margin": 0.0', f'"fusion_margin": {value}'
        )
        assert_refused(http, raw, "space.design.fusion_margin")
    assert_refused(
        http, changed(multi, "space.fusion_margin", 1e300), "space.design.fusion_margin: 1e+300"
    )
    huge = {"name": "x", "low": -1.5e308, "high": 1.5e308}
    assert_refused(http, changed(BOX, "space.params", [huge]), "param 'x': the width")
    for where in ("metadata", "proposer.options", "task.options"):
        body = changed(example("stand-up"), where, {"k": 0.5})
        assert_refused(http, json.dumps(body).replace("0.5", "NaN"), "numbers must be finite")
    assert_created(http, changed(multi, "space.fusion_margin", 0.1))


def test_episodes_need_two_steps(http: httpx.Client) -> None:
    stand_up = example("stand-up")
    assert_refused(http, changed(stand_up, "task.episode_steps", 1), "task.episode_steps")
    assert_refused(http, changed(stand_up, "task.options", {"episode_steps": 1}), "episode_steps")
    assert_created(http, changed(stand_up, "task.episode_steps", 2))


def _store_options(database_url: str, study_id: int, options: dict[str, Any]) -> None:
    """What a server before these checks would have stored."""
    engine = sa.create_engine(database_url)
    try:
        with engine.begin() as connection:
            proposer = connection.execute(
                sa.text("SELECT proposer FROM studies WHERE id = :id"), {"id": study_id}
            ).scalar_one()
            proposer = json.loads(proposer) if isinstance(proposer, str) else proposer
            proposer["options"] = options
            connection.execute(
                sa.text("UPDATE studies SET proposer = :proposer WHERE id = :id"),
                {"proposer": json.dumps(proposer), "id": study_id},
            )
    finally:
        engine.dispose()


def test_stored_bad_proposer_options_answer_409_and_do_not_block_leases(
    live_server: ServerProcess, own_http: httpx.Client
) -> None:
    asked_studies = {
        name: assert_created(own_http, BOX | {"proposer": {"name": name, "n_initial": 1}})["id"]
        for name in ("qei", "tpe", "nelder-mead", "random")
    }
    broken_managed = assert_created(own_http, example("stand-up"))["id"]
    good_managed = assert_created(own_http, changed(example("stand-up"), "proposer.name", "random"))
    bad = {
        "qei": {"num_restarts": "x"},
        "tpe": {"n_startup_trials": "ten"},
        "nelder-mead": {"initial_step": "big"},
        "random": {"colour": "red"},
    }
    live_server.stop()
    for name, study_id in asked_studies.items():
        _store_options(live_server.database_url, study_id, bad[name])
    _store_options(live_server.database_url, broken_managed, {"kernel": "matern52"})
    live_server.start()

    for name, study_id in asked_studies.items():
        for _ in range(2):  # the second ask comes from the cached study config
            response = own_http.post(f"/api/v1/studies/{study_id}/ask", json={"count": 1})
            assert response.status_code == 409, (name, response.text)
            answer = response.json()
            assert answer["error"] == "invalid_study"
            (option,) = bad[name]
            assert answer["problems"][0].startswith(f"proposer.options.{option}:"), answer
        assert own_http.get(f"/api/v1/studies/{study_id}").json()["n_trials"] == 0
    assert own_http.get("/api/v1/studies").status_code == 200

    # The broken managed study is older, so it is asked first: it is skipped.
    job = own_http.post("/api/v1/jobs/lease", json={"worker_id": "w1"})
    assert job.status_code == 200, job.text
    assert job.json()["study_id"] == good_managed["id"]
    assert own_http.get(f"/api/v1/studies/{broken_managed}").json()["n_trials"] == 0
