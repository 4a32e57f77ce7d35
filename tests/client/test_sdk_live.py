"""The SDK end to end against a real ``adserver`` process on a SQLite file."""

from __future__ import annotations

import csv
import io
import json
import threading
import time
from collections.abc import Callable, Iterator

import numpy as np
import pytest

from adclient import Client, Conflict, Invalid, NotFound, PayloadTooLarge
from adclient.client import StudyHandle, study_finished
from adclient.schemas import (
    MAX_TRIAL_PAGE,
    BoxParam,
    BoxSpace,
    ProposerConfig,
    Study,
    StudyCreate,
    Trial,
)
from adclient.testing.servers import ServerProcess

BOX = {"type": "box", "params": [{"name": "x", "low": -2.0, "high": 2.0}]}
RANDOM = {"name": "random", "seed": 3}


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    """One server for the module; every test makes its own studies."""
    workdir = tmp_path_factory.mktemp("sdk-server")
    process = ServerProcess(
        database_url=f"sqlite:///{workdir / 'studies.db'}",
        workdir=workdir,
        env={"AD_MAX_ARTIFACT_BYTES": "4096"},
    ).start()
    yield process
    process.stop()


def box_study(client: Client, name: str, **fields: object) -> StudyHandle:
    return client.create_study(name=name, space=BOX, proposer=RANDOM, **fields)


def test_create_study_from_keywords_model_or_dict(client: Client) -> None:
    by_keywords = box_study(client, "kw", direction="minimize", max_trials=3)
    model = StudyCreate(
        name="model",
        space=BoxSpace(type="box", params=[BoxParam(name="x", low=-2, high=2)]),
        proposer=ProposerConfig(name="random"),
    )
    by_model = client.create_study(model)
    by_dict = client.create_study({"name": "dict", "space": BOX, "proposer": RANDOM})
    overridden = client.create_study({"name": "old", "space": BOX, "proposer": RANDOM}, name="new")

    assert by_keywords.info.direction == "minimize"
    assert by_keywords.info.max_trials == 3
    assert by_model.name == "model"
    assert by_model.info.direction == "maximize"  # the contract's default
    assert by_dict.info.proposer.name == "random"
    assert overridden.name == "new"
    ids = {by_keywords.id, by_model.id, by_dict.id, overridden.id}
    assert len(ids) == 4
    assert ids <= {study.id for study in client.studies()}
    assert client.get_study(by_dict.id).name == "dict"


def test_bad_study_is_invalid_naming_the_field(client: Client) -> None:
    bad = {"type": "box", "params": [{"name": "x", "low": 1.0, "high": 1.0}]}
    with pytest.raises(Invalid) as caught:
        client.create_study(name="bad", space=bad, proposer=RANDOM)
    assert caught.value.status_code == 422
    assert "low" in caught.value.message and "high" in caught.value.message


def test_unknown_ids_are_not_found(client: Client) -> None:
    with pytest.raises(NotFound):
        client.get_study(987654)
    with pytest.raises(NotFound):
        client.best_trial(987654)
    with pytest.raises(NotFound):
        client.tell(987654, 1.0)
    with pytest.raises(NotFound):
        client.get_trial(987654)


def test_ask_tell_best_and_trials(client: Client) -> None:
    study = box_study(client, "asktell", direction="minimize")
    assert study.best_trial is None

    first = study.ask()
    assert isinstance(first, Trial) and first.state == "running"
    batch = study.ask(count=3)
    assert [trial.number for trial in batch] == [1, 2, 3]

    values = {}
    for trial in [first, *batch[:2]]:
        values[trial.id] = trial.params["x"] ** 2
        told = study.tell(trial, values[trial.id], metrics={"abs_x": abs(trial.params["x"])})
        assert told.state == "complete" and told.value == values[trial.id]
    failed = study.tell(batch[2].id, state="failed", message="simulator diverged")
    assert failed.state == "failed" and failed.message == "simulator diverged"

    best = study.best_trial
    assert best is not None and best.value == min(values.values())
    assert study.best_value == best.value
    assert study.best_params == best.params
    assert [trial.number for trial in study.trials] == [0, 1, 2, 3]
    assert {trial.id for trial in study.get_trials("complete")} == set(values)
    assert [trial.id for trial in study.get_trials("failed")] == [batch[2].id]
    info = study.info
    assert (info.n_trials, info.n_complete, info.n_failed) == (4, 3, 1)
    assert client.get_trial(first.id).metrics == {"abs_x": abs(first.params["x"])}


def test_repeated_tell_is_harmless_and_a_contradiction_conflicts(client: Client) -> None:
    study = box_study(client, "repeat")
    trial = study.ask()
    once = study.tell(trial, 0.25)
    twice = study.tell(trial, 0.25)
    assert once.value == twice.value == 0.25
    with pytest.raises(Conflict):
        study.tell(trial, 0.5)
    assert study.info.n_complete == 1


def test_optimize_tells_values_failures_and_reraises(client: Client) -> None:
    study = box_study(client, "optimize", direction="minimize", max_trials=10)
    calls: list[int] = []

    def objective(trial: Trial) -> float | None:
        calls.append(trial.number)
        if trial.number == 1:
            raise RuntimeError("bad luck")
        if trial.number == 2:
            return float("nan")
        return (trial.params["x"] - 1.0) ** 2

    seen: list[int] = []
    told = study.optimize(
        objective, 4, catch=RuntimeError, callbacks=[lambda _s, t: seen.append(t.number)]
    )
    assert [trial.state for trial in told] == ["complete", "failed", "failed", "complete"]
    assert "RuntimeError: bad luck" in (told[1].message or "")
    assert "nan" in (told[2].message or "")
    assert seen == [0, 1, 2, 3], "as Optuna: callbacks see caught failures too"

    def broken(trial: Trial) -> float:
        raise KeyError("missing")

    with pytest.raises(KeyError):
        study.optimize(broken, 3)
    last = study.trials[-1]
    assert last.state == "failed" and "KeyError" in (last.message or "")
    assert study.info.n_trials == 5, "re-raised after the first failure"


def test_optimize_runs_n_jobs_trials_at_once(client: Client) -> None:
    study = box_study(client, "parallel", direction="minimize")
    gate = threading.Barrier(3, timeout=60)
    threads: set[str] = set()

    def objective(trial: Trial) -> float:
        threads.add(threading.current_thread().name)
        gate.wait()  # passes only while three trials are evaluated at once
        return trial.params["x"] ** 2

    told = study.optimize(objective, 9, n_jobs=3)
    assert len(told) == 9 and {trial.state for trial in told} == {"complete"}
    assert len(threads) == 3
    assert sorted(trial.number for trial in told) == list(range(9))
    assert study.info.n_complete == 9


def test_optimize_in_threads_stops_starting_trials_at_an_uncaught_error(client: Client) -> None:
    study = box_study(client, "parallel-error")

    def objective(trial: Trial) -> float:
        if trial.number == 2:
            raise ZeroDivisionError("boom")
        return trial.params["x"]

    with pytest.raises(ZeroDivisionError, match="boom"):
        study.optimize(objective, 50, n_jobs=2, catch=(ValueError,))
    info = study.info
    assert info.n_trials < 50, "no new trials after the error"
    assert info.n_running == 0, "every trial asked was told"
    failed = {trial.number: trial.message for trial in study.get_trials("failed")}
    assert list(failed) == [2] and "ZeroDivisionError: boom" in (failed[2] or "")


def test_optimize_stops_starting_trials_at_the_timeout(client: Client) -> None:
    """A thread of ``optimize`` takes its next trial only after its last one ended and
    was told, and only before the deadline, which is at most 1 s after the first trial
    started. So in each thread every trial but the last ended before that: a check the
    machine's speed cannot fail (an ask or tell slow under load only starts fewer
    trials), and one an optimize that ignored the timeout would fail at once."""
    study = box_study(client, "timeout")
    runs: dict[int, list[tuple[float, float]]] = {}

    def objective(trial: Trial) -> float:
        start = time.monotonic()
        time.sleep(0.2)
        runs.setdefault(threading.get_ident(), []).append((start, time.monotonic()))
        return trial.params["x"]

    told = study.optimize(objective, timeout=1.0, n_jobs=2)
    assert 2 <= len(told) < 40
    first = min(start for thread in runs.values() for start, _ in thread)
    for thread in runs.values():
        ends = [end for _, end in thread[:-1]]
        assert all(end < first + 1.0 for end in ends), "a trial started after the timeout"
    assert study.info.n_running == 0 and study.info.n_complete == len(told)


def test_optimize_without_n_trials_ends_when_the_study_is_full(client: Client) -> None:
    study = box_study(client, "until-full", max_trials=5)
    told = study.optimize(lambda trial: trial.params["x"], n_jobs=2)
    assert len(told) == 5 and study_finished(study.info)
    with pytest.raises(Conflict, match="takes no new trials"):
        study.optimize(lambda trial: trial.params["x"], 1)


def test_wait_returns_once_the_budget_is_spent(client: Client) -> None:
    study = box_study(client, "budget", max_trials=2)
    study.optimize(lambda trial: trial.params["x"], 2)
    updates: list[Study] = []
    info = study.wait(poll=0.01, on_update=updates.append)
    assert study_finished(info)
    assert info.n_complete == 2 and len(updates) == 1


def test_stop_ends_the_study(client: Client) -> None:
    study = box_study(client, "stopme")
    stopped = study.stop()
    assert stopped.state == "stopped"
    assert study_finished(stopped)
    with pytest.raises(Conflict):
        study.ask()


def test_worker_calls_lease_heartbeat_artifacts_tell(client: Client) -> None:
    study = box_study(client, "managed", task={"name": "stand-up", "external": True}, max_trials=1)
    # the other studies of this module run unmanaged: leasing must leave them alone
    job = client.lease("sdk-worker")
    assert job is not None and job.study_id == study.id
    assert job.task.name == "stand-up"
    assert job.params.keys() == {"x"}

    beat = client.heartbeat(job.trial_id, "sdk-worker")
    assert beat.trial_id == job.trial_id
    with pytest.raises(Conflict):
        client.heartbeat(job.trial_id, "someone-else")

    blob = bytes(range(256)) * 8
    stored = client.put_artifact(job.trial_id, "curve.bin", blob, "application/x-curve")
    assert stored.size == len(blob)
    assert client.get_artifact(job.trial_id, "curve.bin") == blob
    assert [item.name for item in client.artifacts(job.trial_id)] == ["curve.bin"]
    # a name travels as one path segment: never another artifact, path or query (sent
    # as written, "curve.bin?x=1" read curve.bin); the server names what it refuses
    for hostile, refused in (
        ("curve.bin?x=1", Invalid),
        ("curve.bin#x", Invalid),
        ("../curve.bin", NotFound),  # no route holds a "/" in a name
        ("a/../curve.bin", NotFound),
    ):
        with pytest.raises(refused, match="path.name" if refused is Invalid else "no API path"):
            client.get_artifact(job.trial_id, hostile)
        with pytest.raises(refused):
            client.put_artifact(job.trial_id, hostile, b"x")
    assert [item.name for item in client.artifacts(job.trial_id)] == ["curve.bin"]
    with pytest.raises(PayloadTooLarge):
        client.put_artifact(job.trial_id, "huge.bin", b"x" * 5000)
    with pytest.raises(NotFound):
        client.get_artifact(job.trial_id, "huge.bin")

    done = client.tell(job.trial_id, 2.5, worker_id="sdk-worker", metrics={"steps": 10})
    assert done.state == "complete" and done.worker_id == "sdk-worker"
    assert [worker.worker_id for worker in study.workers()] == ["sdk-worker"]
    assert client.lease("sdk-worker") is None, "budget spent, and no other study is managed"
    assert study.info.n_trials == 1


def test_export_json_and_csv_hold_every_trial(client: Client) -> None:
    study = box_study(client, "export", direction="minimize")
    study.optimize(lambda trial: trial.params["x"] ** 2, 3)
    failed = study.ask()
    study.tell(failed, state="failed", message='a, "quoted"\nmessage')

    exported = json.loads(study.export("json"))
    assert exported["study"]["id"] == study.id
    assert [trial["number"] for trial in exported["trials"]] == [0, 1, 2, 3]

    rows = list(csv.DictReader(io.StringIO(client.export(study.id, "csv"))))
    assert [row["state"] for row in rows] == ["complete"] * 3 + ["failed"]
    by_number = {trial.number: trial for trial in study.trials}
    for row in rows[:3]:
        trial = by_number[int(row["number"])]
        assert float(row["value"]) == trial.value
        assert float(row["params_x"]) == trial.params["x"]
    assert rows[3]["message"] == 'a, "quoted"\nmessage'
    assert rows[3]["value"] == ""
    with pytest.raises(ValueError):
        client.export(study.id, "xml")  # type: ignore[arg-type, unused-ignore]


def test_trials_and_export_page_past_the_servers_largest_page(client: Client) -> None:
    """The server answers at most MAX_TRIAL_PAGE trials a request; the SDK still gives
    every trial, and a state filter or a slice across page boundaries."""
    study = box_study(client, "long")
    total = 2 * MAX_TRIAL_PAGE + 100
    asked = [trial for start in range(0, total, 64) for trial in study.ask(min(64, total - start))]
    for trial in asked[: MAX_TRIAL_PAGE + 50]:
        if trial.number % 2 == 0 or trial.number > 50:
            study.tell(trial, float(trial.number))

    trials = client.trials(study.id)
    assert [trial.number for trial in trials] == list(range(total))
    complete = client.trials(study.id, "complete")
    assert len(complete) > MAX_TRIAL_PAGE
    assert [t.number for t in complete] == [t.number for t in trials if t.state == "complete"]
    window = client.trials(study.id, offset=MAX_TRIAL_PAGE - 5, limit=MAX_TRIAL_PAGE + 10)
    assert [t.number for t in window] == list(range(MAX_TRIAL_PAGE - 5, 2 * MAX_TRIAL_PAGE + 5))
    assert len(json.loads(study.export("json"))["trials"]) == total


def test_client_closes_its_connection_pool(server: ServerProcess) -> None:
    make: Callable[[], Client] = lambda: Client(server.url)  # noqa: E731
    with make() as api:
        assert api.health()
    assert api._http.is_closed


def test_numpy_values_travel_as_the_numbers_they_hold(client: Client) -> None:
    """A script computes params, values and attributes with NumPy: scalars, arrays and a
    0-d array go as the plain numbers they hold (json could not send them before)."""
    study = box_study(client, "numpy")
    (first, second) = study.ask(count=np.int64(2))
    told = study.tell(first, np.array(0.25), metrics={"m": np.float32(0.5)})
    assert (told.value, told.metrics) == (0.25, {"m": 0.5})
    study.tell(second, np.float32(1.5))
    queued = study.enqueue_trial({"x": np.float32(0.5)})
    assert queued.params == {"x": 0.5}
    added = study.add_trial({"x": np.float64(-1.0)}, np.int64(3))
    assert (added.params, added.value) == ({"x": -1.0}, 3.0)
    study.set_user_attr("scores", np.arange(3))
    study.set_user_attr("flag", np.bool_(True))
    assert study.info.user_attrs == {"scores": [0, 1, 2], "flag": True}
