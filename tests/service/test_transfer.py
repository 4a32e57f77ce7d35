"""Issue 27, the service's side of ``task.transfer``: which evaluated design a leased
job's controller starts from, and where a trial's controller started, as a real
``adserver`` keeps it. Workers of our own (SDK lease, artifact upload, tell) stand in
for adworker here, which tests/workers/test_transfer_worker_e2e.py runs for real.
Issue 36: only a worker's checkpoint of the completing lease is ever a source, and a
scan that fails still leases the job."""

from __future__ import annotations

import csv
import io
from collections.abc import Callable
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
import sqlalchemy as sa
import yaml

from adclient import Client
from adclient.decode import spec_vector, used_slots
from adclient.errors import Invalid
from adclient.pruning import CHECKPOINT_ARTIFACT
from adclient.schemas import Job
from adclient.testing.servers import SDK_HEADERS, ServerProcess, make_token
from adservice.models import TrialRow

pytestmark = [pytest.mark.e2e, pytest.mark.xdist_group("transfer")]

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
AMONG = 2


def study_body(study: str, **task: Any) -> dict[str, Any]:
    """examples/multi-structure.yaml (six trees, eight free joint angles) as a study of
    workers of our own with transfer on."""
    body = yaml.safe_load((EXAMPLES / "multi-structure.yaml").read_text())
    body["proposer"] = {"name": "random", "seed": 7}
    body["task"] = {
        "name": "lift-highest",
        "external": True,
        "transfer": "nearest",
        "transfer_among": AMONG,
        **task,
    }
    return {**body, "name": study, "max_trials": 40}


def key(job: Job, vector: list[float]) -> tuple[int, np.ndarray]:
    assert job.representation is not None
    return spec_vector(job.representation, vector)


def values_of(vector: list[float]) -> tuple[float, float]:
    """Two made-up outcomes of a design, neither monotone in the other."""
    total = float(np.sum(vector))
    return float(np.sin(3 * total)), float(np.cos(5 * total))


OBJECTIVES: dict[str, dict[str, Any]] = {
    "maximize": {},
    "minimize under a constraint": {
        "direction": "minimize",
        "constraints": [{"metric": "c", "op": "<=", "bound": 0.0}],
    },
    "two objectives": {"directions": ["maximize", "minimize"]},
}


def best_of(kind: str, same: list[tuple[int, list[float]]]) -> list[int]:
    """The ids a source may be chosen from, as the study's objectives rank them: the
    ``AMONG`` best feasible ones, or with two objectives the non-dominated ones."""
    if kind == "maximize":
        return [i for i, v in sorted(same, key=lambda row: (-values_of(row[1])[0], row[0]))][:AMONG]
    if kind == "minimize under a constraint":
        feasible = [(i, v) for i, v in same if values_of(v)[1] <= 0.0]
        return [i for i, v in sorted(feasible, key=lambda row: (values_of(row[1])[0], row[0]))][
            :AMONG
        ]
    return [
        i
        for i, v in same
        if not any(
            values_of(w)[0] >= values_of(v)[0]
            and values_of(w)[1] <= values_of(v)[1]
            and values_of(w) != values_of(v)
            for _, w in same
        )
    ]


def tell(client: Client, kind: str, job: Job, source: int | None):
    first, second = values_of(job.vector)
    if kind == "two objectives":
        return client.tell(job.trial_id, [first, second], worker_id="w", transfer_from=source)
    metrics = {"c": second} if kind == "minimize under a constraint" else None
    return client.tell(job.trial_id, first, metrics=metrics, worker_id="w", transfer_from=source)


@pytest.mark.parametrize("kind", OBJECTIVES)
def test_a_job_starts_from_the_nearest_of_the_best_evaluated_designs_of_its_tree(
    shared_server: ServerProcess, kind: str
) -> None:
    """Every leased job is checked against what the service has seen: a job of a tree
    with evaluated designs that left a checkpoint starts from the nearest of the best of
    them (the ``transfer_among`` best by the study's objective, infeasible ones never;
    with two objectives, the non-dominated ones); one of a tree without any starts from
    nothing; a design of another tree, or one that left no checkpoint, is never a
    source. The tell's answer names the source (it was read before the source was kept
    in a constrained or two-objective study)."""
    task = "nearest-" + kind.replace(" ", "-")  # this study's jobs alone, on a shared server
    with Client(shared_server.url) as client:
        body = {**study_body(f"transfer-{kind}", name=task), **OBJECTIVES[kind]}
        study = client.create_study(body)
        done: list[tuple[int, list[float]]] = []  # id, vector (checkpointed)
        started_from = 0
        for index in range(40):
            job = client.lease("w", tasks=[task])
            assert job is not None and job.study_id == study.id
            tree, specs = key(job, job.vector)
            same = [(i, v) for i, v in done if key(job, v)[0] == tree]
            best = best_of(kind, same)
            if not best:
                assert job.transfer is None, (index, job.transfer)
            else:
                assert job.transfer is not None and job.transfer.artifact == CHECKPOINT_ARTIFACT
                assert job.representation is not None
                used = used_slots(
                    job.representation.spec_names, job.representation.structures[tree]
                )
                distances = {
                    i: float(np.sqrt(np.mean((key(job, v)[1][used] - specs[used]) ** 2)))
                    for i, v in same
                    if i in best
                }
                assert job.transfer.trial_id == min(distances, key=lambda i: (distances[i], i))
                assert job.transfer.distance == pytest.approx(distances[job.transfer.trial_id])
                started_from += 1
            if index % 3 != 2:  # every third design leaves no checkpoint: never a source
                client.put_artifact(job.trial_id, CHECKPOINT_ARTIFACT, b"PK", worker_id="w")
                done.append((job.trial_id, job.vector))
            source = job.transfer.trial_id if job.transfer is not None else None
            told = tell(client, kind, job, source)
            assert told.info.get("transfer_from") == source
        assert started_from >= 20  # six trees, 40 designs: most start from another


def test_a_checkpoint_of_an_earlier_attempt_is_no_source(shared_server: ServerProcess) -> None:
    """A trial that uploaded its checkpoint, lost its lease (here: gave it back) and
    was completed by a later attempt that uploaded none (as a promoted trial whose
    final upload failed holds its rung's) is no source: only a checkpoint of the attempt
    that completed a trial is its final controller. One uploaded by that attempt is."""
    mine = ["attempts"]  # this study's jobs alone, on a shared server
    with Client(shared_server.url) as client:
        study = client.create_study(study_body("transfer-attempts", name="attempts"))
        first = client.lease("w", tasks=mine)
        assert first is not None
        client.put_artifact(first.trial_id, CHECKPOINT_ARTIFACT, b"PK", worker_id="w")
        client.release(first.trial_id, "w")
        again = client.lease("w", tasks=mine)
        assert again is not None and again.trial_id == first.trial_id  # a new attempt
        client.tell(first.trial_id, 1.0, worker_id="w")
        assert [a.name for a in client.artifacts(first.trial_id)] == [CHECKPOINT_ARTIFACT]

        client.add_trials(study.id, [{"params": first.params}, {"params": first.params}])
        second = client.lease("w", tasks=mine)
        assert second is not None and key(second, second.vector)[0] == key(first, first.vector)[0]
        assert second.transfer is None, second.transfer
        client.put_artifact(second.trial_id, CHECKPOINT_ARTIFACT, b"PK", worker_id="w")
        client.tell(second.trial_id, 0.5, worker_id="w")
        third = client.lease("w", tasks=mine)
        assert third is not None and third.transfer is not None
        assert third.transfer.trial_id == second.trial_id


def test_transfer_from_names_another_trial_of_the_same_study_or_nothing_is_stored(
    shared_server: ServerProcess,
) -> None:
    """A tell naming a trial of another study, the trial itself, one still running or
    one completed without a checkpoint, a tell in a study without ``task.transfer``,
    and a tell or pause naming ``true`` or an id past the database's integers, are
    refused and leave the trial running; a right one is kept in its info and exports."""
    with Client(shared_server.url) as client:
        study = client.create_study(study_body("transfer-a", name="alpha"))
        client.create_study(study_body("transfer-b", name="beta"))
        cold = client.create_study({**study_body("transfer-c", name="gamma"), "task": None})
        foreign, source, mine, bare = (
            client.lease("w", tasks=["beta"]),
            client.lease("w", tasks=["alpha"]),
            client.lease("w", tasks=["alpha"]),
            client.lease("w", tasks=["alpha"]),
        )
        assert foreign and source and mine and bare
        client.tell(bare.trial_id, 0.9, worker_id="w")  # complete, no checkpoint
        for wrong in (foreign.trial_id, mine.trial_id, source.trial_id, bare.trial_id):
            with pytest.raises(Invalid, match="transfer_from"):
                client.tell(mine.trial_id, 1.0, worker_id="w", transfer_from=wrong)
            assert client.get_trial(mine.trial_id).state == "running"
        for route, body in (("tell", {"value": 1.0}), ("pause", {"step": 1})):
            for wrong in (2**70, True):
                refused = httpx.post(
                    f"{shared_server.url}/api/v1/trials/{mine.trial_id}/{route}",
                    json={**body, "worker_id": "w", "transfer_from": wrong},
                    headers=SDK_HEADERS,
                )
                assert refused.status_code == 422 and "transfer_from" in refused.text, refused.text
                assert client.get_trial(mine.trial_id).state == "running"
        client.put_artifact(source.trial_id, CHECKPOINT_ARTIFACT, b"PK", worker_id="w")
        client.tell(source.trial_id, 0.5, worker_id="w")
        (asked,) = client.ask(cold.id)
        with pytest.raises(Invalid, match=r"no task\.transfer"):
            client.tell(asked.id, 1.0, transfer_from=source.trial_id)
        assert client.get_trial(asked.id).state == "running"
        told = client.tell(mine.trial_id, 0.7, worker_id="w", transfer_from=source.trial_id)
        assert told.info["transfer_from"] == source.trial_id
        rows = csv.DictReader(io.StringIO(client.export(study.id, "csv")))
        cells = {row["id"]: row["transfer_from"] for row in rows}
        assert cells == {
            str(source.trial_id): "",
            str(mine.trial_id): str(source.trial_id),
            str(bare.trial_id): "",
        }


def test_a_learner_that_cannot_start_from_another_controller_is_refused(
    shared_server: ServerProcess,
) -> None:
    with Client(shared_server.url) as client:
        body = study_body("transfer-fast")
        body["task"] = {"name": "lift-highest", "learner": "fast", "transfer": "nearest"}
        with pytest.raises(Invalid, match="learner 'fast' cannot start from another"):
            client.create_study(body)
        assert all(s.name != "transfer-fast" for s in client.studies())


BOX = {
    "name": "box-transfer",
    "space": {"type": "box", "params": [{"name": "x", "low": 0, "high": 1}]},
    "proposer": {"name": "random", "seed": 1},
    "task": {"name": "curve", "external": True, "transfer": "nearest"},
    "max_trials": 20,
}


def as_token(server: ServerProcess, role: str) -> httpx.Client:
    token = make_token(server, role)
    headers = {"Authorization": f"Bearer {token}", **SDK_HEADERS}
    return httpx.Client(base_url=server.url, headers=headers, timeout=30)


def done(api: httpx.Client, trial_id: int, worker: str | None, value: float) -> None:
    """Upload a checkpoint to a trial (under ``worker``'s lease, or as the owner of an
    asked trial), then tell it ``value``."""
    lease = {"worker_id": worker} if worker else {}
    put = api.put(
        f"/api/v1/trials/{trial_id}/artifacts/{CHECKPOINT_ARTIFACT}", params=lease, content=b"PK"
    )
    assert put.status_code == 201, put.text
    told = api.post(f"/api/v1/trials/{trial_id}/tell", json={"value": value, **lease})
    assert told.status_code == 200, told.text


def test_a_checkpoint_a_user_uploaded_is_never_a_source(
    server_factory: Callable[..., ServerProcess],
) -> None:
    """Issue 36: the owner of a study with transfer asks a trial itself, uploads its
    checkpoint and tells it the study's best value; it also leases a job with its user
    token, uploads under that lease and tells the next best. Neither is a source of a
    worker's job, nor may a tell name it; a worker token's upload under the lease that
    completed its trial is the source of the next job."""
    secured = server_factory(AD_AUTH="true")
    with as_token(secured, "user") as owner, as_token(secured, "worker") as worker:
        created = owner.post("/api/v1/studies", json=BOX)
        assert created.status_code == 201, created.text
        asked = owner.post(f"/api/v1/studies/{created.json()['id']}/ask", json={})
        done(owner, asked.json()["trials"][0]["id"], None, 100.0)
        own = owner.post("/api/v1/jobs/lease", json={"worker_id": "u"}).json()
        done(owner, own["trial_id"], "u", 90.0)

        job = worker.post("/api/v1/jobs/lease", json={"worker_id": "w"}).json()
        assert job["transfer"] is None, job["transfer"]
        for untrusted in (asked.json()["trials"][0]["id"], own["trial_id"]):
            named = {"value": 1.0, "worker_id": "w", "transfer_from": untrusted}
            refused = worker.post(f"/api/v1/trials/{job['trial_id']}/tell", json=named)
            assert refused.status_code == 422 and "worker uploaded" in refused.text, refused.text
        done(worker, job["trial_id"], "w", 1.0)
        following = worker.post("/api/v1/jobs/lease", json={"worker_id": "w"}).json()
        assert following["transfer"]["trial_id"] == job["trial_id"], following


def test_a_transfer_scan_that_fails_still_leases_the_job(shared_server: ServerProcess) -> None:
    """Choosing a source raises here for real: a checkpointed trial's stored vector is
    made undecodable straight in the database (``["not a number"]``, as corruption or a
    hand edit would leave it). The next job is leased all the same, without a source,
    the reason is in the server's log, and its worker tells it."""
    mine = ["scan-fails"]  # this study's jobs alone, on a shared server
    with Client(shared_server.url) as client:
        study = client.create_study({**BOX, "task": {**BOX["task"], "name": mine[0]}})
        first = client.lease("w", tasks=mine)
        assert first is not None
        client.put_artifact(first.trial_id, CHECKPOINT_ARTIFACT, b"PK", worker_id="w")
        client.tell(first.trial_id, 1.0, worker_id="w")
        client.add_trials(study.id, [{"params": {"x": 0.5}}])  # leased next, no proposal
        engine = sa.create_engine(shared_server.database_url)
        with engine.begin() as connection:
            connection.execute(
                sa.update(TrialRow.__table__)
                .where(TrialRow.__table__.c.id == first.trial_id)
                .values(vector=["not a number"])
            )
        engine.dispose()
        job = client.lease("w", tasks=mine)
        assert job is not None and job.params == {"x": 0.5} and job.transfer is None
        log = shared_server.log_path.read_text()
        assert f"trial {job.trial_id}: no transfer source (ValueError" in log, log[-2000:]
        assert client.tell(job.trial_id, 0.5, worker_id="w").state == "complete"
