"""Every design space the server accepts can be asked, enqueued, decoded and leased
(issue 36: a space with a tie to the root was created, and every ask answered 500).

Hypothesis draws spaces from every feature of the model (``any_spaces``: trees, ties,
mirrors, catalogues, joint kinds, overrides, shapes, spec constraints, encodings) and
creates each on the real app over a SQLite file, in process so that many run. A refused
space is a 422 that stores nothing. An accepted one asks with every proposer (after a
few told trials, so the model-based ones fit), its asked params enqueue back to the
same params, and a worker leases each of them and one more it proposes, builds the
robot as adworker does (``job_robot``) and PyBullet loads its URDF.
tests/workers/test_root_ties_e2e.py runs the issue's spaces on a real adserver and
adworker.
"""

from __future__ import annotations

import contextlib
import os
import sqlite3
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pybullet
import pytest
import yaml
from fastapi.testclient import TestClient
from hypothesis import HealthCheck, Phase, event, example, given, settings

from adclient.design import DesignSpace
from adclient.schemas import Job
from adclient.testing.servers import SDK_HEADERS
from adservice.app import create_app
from adservice.proposers import available
from adservice.settings import Settings
from adworker.job_robots import job_robot
from tests.client.design_strategies import any_spaces
from tests.service.conftest import LOCAL

pytestmark = pytest.mark.slow

PROPOSERS: dict[str, dict[str, Any]] = {
    "random": {},
    "sobol": {},
    "nelder-mead": {},
    "qei": {"num_restarts": 2, "raw_samples": 32, "maxiter": 20},
    "tpe": {"n_startup_trials": 2},
}
"""Every proposer, with options that keep a model-based one's ask short."""


@pytest.fixture(scope="module")
def database_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("spaces") / "studies.db"


@pytest.fixture(scope="module")
def app(database_file: Path) -> Iterator[TestClient]:
    settings = Settings(
        database_url=f"sqlite:///{database_file}", artifact_dir=database_file.parent / "artifacts"
    )
    with TestClient(create_app(settings), base_url=LOCAL, headers=SDK_HEADERS) as client:
        yield client


def stored_rows(database: Path) -> dict[str, int]:
    """Rows in every table of the app's SQLite file, read straight from it (a listing
    over the API grows with every study the module's examples made)."""
    with contextlib.closing(sqlite3.connect(database)) as connection:
        tables = [
            name
            for (name,) in connection.execute("SELECT name FROM sqlite_master WHERE type = 'table'")
        ]
        return {
            table: connection.execute(f'SELECT count(*) FROM "{table}"').fetchone()[0]
            for table in tables
        }


@pytest.fixture(scope="module")
def physics() -> Iterator[int]:
    client = pybullet.connect(pybullet.DIRECT)
    yield client
    pybullet.disconnect(client)


ONE_DESIGN = yaml.safe_load(
    (Path(__file__).resolve().parents[2] / "examples" / "one-design.yaml").read_text()
)["space"]


def test_every_proposer_is_tried() -> None:
    assert sorted(PROPOSERS) == available()


@settings(
    max_examples=40,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow],
    phases=[Phase.explicit, Phase.reuse, Phase.generate],  # shrinking one takes minutes
)
@given(space=any_spaces())
@example(space=ONE_DESIGN)  # a space that searches nothing is one design (issue 39)
def test_every_space_the_server_accepts_asks_enqueues_decodes_and_leases(
    app: TestClient, database_file: Path, physics: int, space: dict[str, Any]
) -> None:
    before = stored_rows(database_file)
    created = _create(app, space, "random")
    if created.status_code != 201:
        assert created.status_code == 422, created.text
        assert created.json()["detail"]
        assert stored_rows(database_file) == before
        event("refused")
        return
    event("accepted")
    asked = _ask(app, created.json()["id"])
    for name in PROPOSERS.keys() - {"random"}:
        asked += _ask(app, _create(app, space, name).json()["id"])
    managed = _create(app, space, "random", max_trials=len(asked) + 1).json()["id"]
    enqueued = app.post(
        f"/api/v1/studies/{managed}/trials", json=[{"params": params} for params in asked]
    )
    assert enqueued.status_code == 201, enqueued.text
    stored = {trial["id"]: trial["params"] for trial in enqueued.json()}
    exact = _encodes_exactly(DesignSpace.model_validate(created.json()["space"]))
    for params, shown in zip(asked, stored.values(), strict=True):
        assert shown == params if exact else shown["structure"] == params["structure"]
    for _ in range(len(asked) + 1):  # the queued trials, then one the lease proposes
        leased = app.post("/api/v1/jobs/lease", json={"worker_id": "spaces"})
        assert leased.status_code == 200, leased.text
        job = Job.model_validate(leased.json())
        assert job.params == stored.get(job.trial_id, job.params)
        _build_and_load(job, physics)
        told = app.post(
            f"/api/v1/trials/{job.trial_id}/tell", json={"value": 0.0, "worker_id": "spaces"}
        )
        assert told.status_code == 200, told.text
    assert app.post("/api/v1/jobs/lease", json={"worker_id": "spaces"}).status_code == 204


def _create(app: TestClient, space: dict[str, Any], proposer: str, **managed: Any) -> Any:
    body: dict[str, Any] = {
        "name": f"space-{proposer}",
        "space": space,
        "proposer": {"name": proposer, "n_initial": 2, "options": PROPOSERS[proposer]},
    }
    if managed:
        body.update(task={"name": "lift-highest", "learner": "fast"}, **managed)
    return app.post("/api/v1/studies", json=body)


def _ask(app: TestClient, study_id: int) -> list[dict[str, Any]]:
    """Two asked and told (values that differ, so a model has something to fit), then
    one more: the three trials' params."""
    asked = app.post(f"/api/v1/studies/{study_id}/ask", json={"count": 2})
    assert asked.status_code == 200, asked.text
    first = asked.json()["trials"]
    for number, trial in enumerate(first):
        told = app.post(f"/api/v1/trials/{trial['id']}/tell", json={"value": float(number)})
        assert told.status_code == 200, told.text
    more = app.post(f"/api/v1/studies/{study_id}/ask", json={"count": 1})
    assert more.status_code == 200, more.text
    return [trial["params"] for trial in [*first, *more.json()["trials"]]]


def _encodes_exactly(space: DesignSpace) -> bool:
    """Whether params encode back to the very design (a fused representation of several
    structures encodes to the nearest vector its affine maps reach)."""
    return space.encoding != "fused" or len(space.tree_structures()) == 1


def _build_and_load(job: Job, physics: int) -> None:
    """The job's robot as a worker builds it, loaded by PyBullet: one joint per edge."""
    design, urdf = job_robot(job)
    assert design is not None
    handle, name = tempfile.mkstemp(suffix=".urdf")
    try:
        with os.fdopen(handle, "w") as file:
            file.write(urdf)
        body = pybullet.loadURDF(name, physicsClientId=physics)
        assert pybullet.getNumJoints(body, physicsClientId=physics) == len(design.joints)
        pybullet.removeBody(body, physicsClientId=physics)
    finally:
        Path(name).unlink()
