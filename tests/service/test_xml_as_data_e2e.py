"""Issue 58, finding 2, on a real ``adserver`` with auth on and a plain ``user`` token:
a template is XML as data (an entity bomb, a name that injects markup and a visual mesh
are each a 422 naming it, storing nothing); every trial's expansion is checked as the
creation checks are, so one harmful only between the check points fails those trials
and stores none of it; and a harmful URDF an older server stored is refused by the
spawn read off the event loop, the server answering others meanwhile."""

from __future__ import annotations

import statistics
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import httpx
import pytest
import yaml

from adclient.testing.servers import ServerProcess, make_token
from tests.harmful_urdfs import (
    HARMFUL_BETWEEN_SPACE,
    HOSTNAME_MESH,
    entity_bomb,
    store_urdf,
    stored_urdfs,
    with_base,
)

pytestmark = pytest.mark.e2e

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
PARAMS = [{"name": "size", "low": 0.1, "high": 0.2}]


@pytest.fixture(scope="module")
def secured(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    workdir = tmp_path_factory.mktemp("xml-as-data")
    server = ServerProcess(
        database_url=f"sqlite:///{workdir / 'studies.db'}", workdir=workdir, env={"AD_AUTH": "1"}
    )
    yield server.start()
    server.stop()


@pytest.fixture(scope="module")
def user(secured: ServerProcess) -> Iterator[httpx.Client]:
    token = make_token(secured, "user", name="alice")
    with httpx.Client(
        base_url=secured.url,
        headers={"Authorization": f"Bearer {token}"},
        timeout=60,
        verify=False,
    ) as client:
        yield client


def sized(template: str) -> str:
    """The template with its base box's first side the param ``size``."""
    return template.replace('<box size="0.1 0.1 0.1"/>', '<box size="${size} 0.1 0.1"/>', 1)


@pytest.mark.parametrize(
    ("template", "named"),
    [
        pytest.param(
            entity_bomb(references=2).replace('<box size="0.1', '<box size="${size}', 1),
            "line 2: a DOCTYPE is not allowed",
            id="entity bomb",
        ),
        pytest.param(
            sized(with_base("<xacro:element xacro:name=\"link name='evil'\"/>")),
            "an element's name \"link name='evil'\" is not an XML name",
            id="xacro:element",
        ),
        pytest.param(
            sized(with_base(f"<visual><geometry>{HOSTNAME_MESH}</geometry></visual>")),
            "its geometry is <mesh> (in a <visual>)",
            id="visual mesh",
        ),
    ],
)
def test_a_template_that_is_not_data_is_refused_at_creation_naming_the_construct(
    user: httpx.Client, template: str, named: str
) -> None:
    space = {"type": "template", "template": template, "params": PARAMS}
    refused = user.post("/api/v1/studies", json={"name": "refused", "space": space})
    assert refused.status_code == 422, refused.text
    assert named in refused.json()["detail"], refused.json()["detail"]
    assert [s for s in user.get("/api/v1/studies").json() if s["name"] == "refused"] == []


def test_a_template_harmful_only_between_its_check_points_fails_those_trials_alone(
    secured: ServerProcess, user: httpx.Client
) -> None:
    """At n = 1 and 3 the template writes a mesh at a local path (a visual mesh, and
    one made by xacro:element); at 0, 2 and 4, where the creation checks it, nothing
    harmful. Those trials are failed with the reason, and no stored URDF holds it."""
    body = {"name": "between", "space": HARMFUL_BETWEEN_SPACE}
    created = user.post("/api/v1/studies", json={**body, "proposer": {"name": "random", "seed": 1}})
    assert created.status_code == 201, created.text
    study_id = created.json()["id"]
    asked = user.post(f"/api/v1/studies/{study_id}/ask", json={"count": 10})
    assert asked.status_code == 200, asked.text
    trials = asked.json()["trials"]
    assert {trial["params"]["n"] for trial in trials} >= {1, 3}, trials  # seed 1 draws both
    reasons = {
        1: "its geometry is <mesh> (in a <visual>)",
        3: "an element's name \"mesh filename='/etc/hostname'\" is not an XML name",
    }
    for trial in trials:
        n = trial["params"]["n"]
        if n in reasons:
            assert trial["state"] == "failed", trial
            assert reasons[n] in trial["message"], trial["message"]
        else:
            assert trial["state"] == "running", trial
            served = user.get(f"/api/v1/trials/{trial['id']}/urdf")
            assert served.status_code == 200 and "<mesh" not in served.text
    urdfs = stored_urdfs(secured.database_url)
    assert {trial["id"] for trial in trials} <= set(urdfs)
    assert not [urdf for urdf in urdfs.values() if urdf is not None and "hostname" in urdf]


def latency(http: httpx.Client, path: str) -> float:
    started = time.perf_counter()
    assert http.get(path).status_code == 200
    return time.perf_counter() - started


def test_a_harmful_urdf_an_older_server_stored_fails_its_spawn_read_off_the_event_loop(
    secured: ServerProcess, user: httpx.Client
) -> None:
    """A trial's stored URDF replaced by an entity bomb of a megabyte (expanded, 80 MB
    of text: before issue 58 each spawn read parsed it on the event loop). Its spawn
    read is a 422 naming the DOCTYPE, its URDF is not served, and /healthz answers
    while spawn reads are sent as fast as it does when the server is quiet (medians of
    the same run; before, each spawn read held every other request for its parse)."""
    body: dict[str, Any] = yaml.safe_load((EXAMPLES / "template-arm.yaml").read_text())
    body["space"]["template"] = (EXAMPLES / body["space"]["template"]).read_text()
    body.update(name="stored-bomb", proposer={"name": "random", "seed": 3})
    created = user.post("/api/v1/studies", json=body)
    assert created.status_code == 201, created.text
    asked = user.post(f"/api/v1/studies/{created.json()['id']}/ask", json={"count": 1})
    (trial,) = asked.json()["trials"]
    assert user.get(f"/api/v1/trials/{trial['id']}/spawn").status_code == 200
    store_urdf(secured.database_url, trial["id"], entity_bomb(padding=1_000_000, references=1000))

    spawn = f"/api/v1/trials/{trial['id']}/spawn"
    with httpx.Client(base_url=secured.url, timeout=120, verify=False) as health:
        quiet = [latency(health, "/healthz") for _ in range(15)]

        def spawn_read() -> httpx.Response:
            return user.get(spawn)

        during = []
        with ThreadPoolExecutor(max_workers=1) as pool:
            for _ in range(10):
                answer = pool.submit(spawn_read)
                time.sleep(0.02)  # the spawn read reaches the server first
                during.append(latency(health, "/healthz"))
                refused = answer.result()
                assert refused.status_code == 422, refused.text
                assert "line 2: a DOCTYPE is not allowed" in refused.json()["detail"]
    ratio = statistics.median(during) / statistics.median(quiet)
    assert ratio < 10, (during, quiet)
    served = user.get(f"/api/v1/trials/{trial['id']}/urdf")
    assert served.status_code == 422 and "<!DOCTYPE" in served.json()["detail"], served.text
