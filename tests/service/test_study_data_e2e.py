"""Free-text study names, deleting a study, and user attributes, against a real adserver
on SQLite and on PostgreSQL (issue 16)."""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Callable

import httpx
import pytest
import sqlalchemy as sa

from adclient import Client
from adclient.errors import Conflict, NotFound
from adclient.testing.servers import SDK_HEADERS, ServerProcess, make_token

pytestmark = [pytest.mark.e2e, pytest.mark.xdist_group("study-data")]

NAMES = [
    "Roboter-Entwurf 設計 v2",
    "stand up, long budget",
    "[bold]x[/bold]",
    "<img src=x onerror=alert(1)>",
    "é" * 200,
]
BOX = {"type": "box", "params": [{"name": "x", "low": 0, "high": 1}]}
MANAGED = {
    "name": "managed",
    "space": BOX,
    "proposer": {"name": "random"},
    "task": {"name": "noop", "external": True},
    "max_trials": 10,
}
PNG = b"\x89PNG\r\n\x1a\n" + bytes(64)


def raw(server: ServerProcess, token: str | None = None) -> httpx.Client:
    headers = dict(SDK_HEADERS)
    if token is not None:
        headers["Authorization"] = f"Bearer {token}"
    return httpx.Client(base_url=server.url, headers=headers, timeout=30, verify=False)


def test_names_are_free_text_and_control_characters_are_refused(
    shared_server: ServerProcess,
) -> None:
    with Client(shared_server.url) as client:
        before = [study.name for study in client.studies()]  # the module's other tests'
        made = [client.create_study(name=name, space=BOX).id for name in NAMES]
        assert [client.study_info(study_id).name for study_id in made] == NAMES
        assert [study.name for study in client.studies()] == before + NAMES
    api = raw(shared_server)
    for name, problem in (
        ("line\nbreak", "U+000A at position 4"),
        ("\x1b[31mred", "U+001B at position 0"),
        ("abc\u202edcba", "U+202E at position 3"),
        ("tab\tbed", "U+0009"),
        ("   ", "blank"),
        ("", "at least 1 character"),
        ("x" * 201, "at most 200 characters"),
    ):
        answer = api.post("/api/v1/studies", json={"name": name, "space": BOX})
        assert answer.status_code == 422, name
        problems = answer.json()["problems"]
        assert any("name" in item and problem in item for item in problems), problems
    lone = b'{"name": "half \\ud800", "space": {"type": "box", "params": []}}'
    answer = api.post("/api/v1/studies", content=lone, headers={"Content-Type": "application/json"})
    assert answer.status_code == 422
    assert len(api.get("/api/v1/studies").json()) == len(before) + len(NAMES)


def lease_with_files(api: httpx.Client, worker_id: str, task: str) -> int:
    """Lease a trial of ``task`` as ``worker_id``, report on it and upload two artifacts."""
    lease = {"worker_id": worker_id, "tasks": [task]}
    job = api.post("/api/v1/jobs/lease", json=lease).json()
    trial = f"/api/v1/trials/{job['trial_id']}"
    body = {"worker_id": worker_id, "step": 1, "value": 0.5}
    assert api.post(f"{trial}/report", json=body).status_code == 200
    for name, data in (("robot.png", PNG), ("notes.json", b"{}")):
        put = api.put(f"{trial}/artifacts/{name}?worker_id={worker_id}", content=data)
        assert put.status_code == 201, put.text
    return int(job["trial_id"])


def test_delete_refuses_leases_unless_forced_and_removes_everything(
    shared_server: ServerProcess,
) -> None:
    api = raw(shared_server)
    task = "deleted"  # this test's jobs alone, on a shared server
    body = {**MANAGED, "task": {"name": task, "external": True}}
    doomed = api.post("/api/v1/studies", json={**body, "max_trials": 2}).json()["id"]
    finished = lease_with_files(api, "w1", task)
    assert api.post(f"/api/v1/trials/{finished}/tell", json={"worker_id": "w1", "value": 1.0})
    held = lease_with_files(api, "w2", task)
    kept = api.post("/api/v1/studies", json={**body, "name": "kept"}).json()["id"]
    other = lease_with_files(api, "w3", task)
    assert api.get(f"/api/v1/trials/{other}").json()["study_id"] == kept
    files = shared_server.artifact_dir / str(doomed)
    assert len(list(files.rglob("robot.png.*"))) >= 2
    before = api.get(f"/api/v1/studies/{doomed}/trials").json()

    refused = api.delete(f"/api/v1/studies/{doomed}")
    assert refused.status_code == 409
    assert "'w2'" in refused.json()["detail"] and "force=true" in refused.json()["detail"]
    assert api.get(f"/api/v1/studies/{doomed}/trials").json() == before

    assert api.delete(f"/api/v1/studies/{doomed}", params={"force": "true"}).status_code == 204
    assert api.get(f"/api/v1/studies/{doomed}").status_code == 404
    assert api.delete(f"/api/v1/studies/{doomed}").status_code == 404
    for trial in (finished, held):
        assert api.get(f"/api/v1/trials/{trial}").status_code == 404
        assert api.get(f"/api/v1/trials/{trial}/artifacts/robot.png").status_code == 404
    assert not files.exists()
    # The holder of a cancelled lease is told the trial is gone, whatever it tries.
    path = f"/api/v1/trials/{held}"
    for answer in (
        api.post(f"{path}/heartbeat", json={"worker_id": "w2"}),
        api.post(f"{path}/report", json={"worker_id": "w2", "step": 2, "value": 0.1}),
        api.put(f"{path}/artifacts/late.json?worker_id=w2", content=b"{}"),
        api.patch(path, json={"worker_id": "w2", "user_attrs": {"a": 1}}),
        api.post(f"{path}/tell", json={"worker_id": "w2", "value": 0.1}),
        api.post(f"{path}/release", json={"worker_id": "w2"}),
    ):
        assert answer.status_code == 404, answer.text
        assert answer.json()["detail"] == f"trial {held} not found"
    engine = sa.create_engine(shared_server.database_url)
    with engine.connect() as connection:
        mine = sa.text(  # this test's workers (others lease on the shared server)
            "SELECT worker_id, current_trial_id FROM workers WHERE worker_id IN ('w1', 'w2', 'w3')"
        )
        current = dict(connection.execute(mine).all())
    engine.dispose()
    assert current == {"w1": None, "w2": None, "w3": other}
    # The other study is whole, and a new study never takes the deleted one's id.
    assert api.get(f"/api/v1/studies/{kept}").json()["n_running"] == 1
    assert (
        api.post(f"/api/v1/trials/{other}/heartbeat", json={"worker_id": "w3"}).status_code == 200
    )
    assert (shared_server.artifact_dir / str(kept)).is_dir()
    # Ids are never given again, even those of the newest study and trial.
    newest = api.post("/api/v1/studies", json={"name": "newest", "space": BOX}).json()["id"]
    asked = api.post(f"/api/v1/studies/{newest}/ask", json={}).json()["trials"][0]["id"]
    assert api.delete(f"/api/v1/studies/{newest}").status_code == 204
    again = api.post("/api/v1/studies", json={"name": "again", "space": BOX}).json()["id"]
    assert again > newest
    assert api.post(f"/api/v1/studies/{again}/ask", json={}).json()["trials"][0]["id"] > asked


def test_sdk_delete_and_its_conflict(shared_server: ServerProcess) -> None:
    with Client(shared_server.url) as client:
        study = client.create_study({**MANAGED, "task": {"name": "sdk-delete", "external": True}})
        job = client.lease("w", tasks=["sdk-delete"])
        assert job is not None
        with pytest.raises(Conflict, match="leased by worker"):
            study.delete()
        assert client.study_info(study.id).n_running == 1
        study.delete(force=True)
        with pytest.raises(NotFound):
            client.study_info(study.id)
        with pytest.raises(NotFound):
            client.delete_study(study.id)
        with pytest.raises(NotFound):
            client.heartbeat(job.trial_id, "w")


@pytest.fixture
def secured(server_factory: Callable[..., ServerProcess]) -> ServerProcess:
    return server_factory(AD_AUTH="true")


def test_only_the_owner_or_an_admin_deletes_and_sets_attributes(secured: ServerProcess) -> None:
    owner = raw(secured, make_token(secured, "user", "owner"))
    stranger = raw(secured, make_token(secured, "user", "stranger"))
    worker = raw(secured, make_token(secured, "worker", "worker"))
    other_worker = raw(secured, make_token(secured, "worker", "other"))
    reader = raw(secured, make_token(secured, "reader"))
    admin = raw(secured, make_token(secured, "admin"))
    study = owner.post("/api/v1/studies", json=MANAGED).json()["id"]
    job = worker.post("/api/v1/jobs/lease", json={"worker_id": "w"}).json()
    trial = f"/api/v1/trials/{job['trial_id']}"

    for client, code in ((stranger, 403), (worker, 403), (reader, 403)):
        assert (
            client.patch(f"/api/v1/studies/{study}", json={"user_attrs": {"a": 1}}).status_code
            == code
        )
        assert client.delete(f"/api/v1/studies/{study}?force=true").status_code == code
    assert stranger.patch(trial, json={"user_attrs": {"a": 1}}).status_code == 403
    # A worker token: only on the trial it holds, naming itself.
    no_id = worker.patch(trial, json={"user_attrs": {"a": 1}})
    assert no_id.status_code == 403 and "give worker_id" in no_id.json()["detail"]
    impostor = other_worker.patch(trial, json={"worker_id": "w", "user_attrs": {"a": 1}})
    assert impostor.status_code == 403
    assert admin.get(trial).json()["user_attrs"] == {}

    set_by_worker = worker.patch(trial, json={"worker_id": "w", "user_attrs": {"loss": 0.25}})
    assert set_by_worker.status_code == 200
    assert set_by_worker.json()["user_attrs"] == {"loss": 0.25}
    by_owner = owner.patch(trial, json={"user_attrs": {"note": "kept"}})
    assert by_owner.json()["user_attrs"] == {"loss": 0.25, "note": "kept"}
    assert worker.post(f"{trial}/tell", json={"worker_id": "w", "value": 1.0}).status_code == 200
    late = worker.patch(trial, json={"worker_id": "w", "user_attrs": {"late": True}})
    assert late.status_code == 409
    assert owner.patch(f"/api/v1/studies/{study}", json={"user_attrs": {"a": 1}}).status_code == 200

    theirs = stranger.post("/api/v1/studies", json={**MANAGED, "name": "theirs"}).json()["id"]
    assert admin.delete(f"/api/v1/studies/{theirs}").status_code == 204
    assert owner.delete(f"/api/v1/studies/{study}").status_code == 204
    assert admin.get(f"/api/v1/studies/{study}").status_code == 404


def test_user_attributes_merge_and_bad_ones_change_nothing(shared_server: ServerProcess) -> None:
    api = raw(shared_server)
    with Client(shared_server.url) as client:
        study = client.create_study(name="attrs", space=BOX, direction="minimize")
        study.set_user_attr("owner", "Ada 設計")
        study.set_user_attr("budget", {"steps": 1000, "tags": ["a", "b"]})
        study.set_user_attr("owner", None)
        assert study.user_attrs == {"budget": {"steps": 1000, "tags": ["a", "b"]}}
        trial = study.ask()
        trial.set_user_attr("seed", 7)
        trial.set_user_attr("label", "[bold]x[/bold]")
        assert trial.user_attrs == {"seed": 7, "label": "[bold]x[/bold]"}
        study.tell(trial, 0.5)
        assert client.get_trial(trial.id).user_attrs == {"seed": 7, "label": "[bold]x[/bold]"}
        exported = json.loads(study.export("json"))
        assert exported["study"]["user_attrs"] == study.user_attrs
        assert exported["trials"][0]["user_attrs"] == {"seed": 7, "label": "[bold]x[/bold]"}
        row = next(csv.DictReader(io.StringIO(study.export("csv"))))
        assert row["user_attrs_seed"] == "7" and row["user_attrs_label"] == "[bold]x[/bold]"

    stored = api.get(f"/api/v1/studies/{study.id}").json()
    deep: dict = {}
    for _ in range(40):
        deep = {"d": deep}
    big = {f"k{i}": "x" * 1000 for i in range(10)}
    for body, problem in (
        ({"user_attrs": {"deep": deep}}, "nest deeper than 32"),
        ({"user_attrs": {"x": "a\x00b"}}, "NUL"),
        ({"user_attrs": {"": 1}}, "1 to 128 characters"),
        ({"user_attrs": {"a": 1}, "name": "renamed"}, "Extra inputs"),
        ({"user_attrs": [1]}, "valid dictionary"),
    ):
        answer = api.patch(f"/api/v1/studies/{study.id}", json=body)
        assert answer.status_code == 422, body
        assert any(problem in item for item in answer.json()["problems"]), answer.json()
    nan = api.patch(
        f"/api/v1/studies/{study.id}",
        content=b'{"user_attrs": {"x": NaN}}',
        headers={"Content-Type": "application/json"},
    )
    assert nan.status_code == 422 and "finite" in nan.text
    # Each patch alone is within the limit; merged, the second is not.
    assert api.patch(f"/api/v1/studies/{study.id}", json={"user_attrs": big}).status_code == 200
    more = {f"m{i}": "y" * 1000 for i in range(10)}
    answer = api.patch(f"/api/v1/studies/{study.id}", json={"user_attrs": more})
    assert answer.status_code == 422
    assert "merged" in answer.json()["detail"] and "16384" in answer.json()["detail"]
    after = api.get(f"/api/v1/studies/{study.id}").json()
    assert after["user_attrs"] == {**stored["user_attrs"], **big}
    assert api.patch("/api/v1/trials/999999", json={"user_attrs": {"a": 1}}).status_code == 404
