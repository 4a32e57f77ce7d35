"""Per-owner storage quotas (issue 58, finding 4): an owner's studies store at most
``AD_OWNER_STORAGE_BYTES`` of artifacts and template URDFs together. Past it an upload
is 413, the owner's asks and enqueues are 409, and workers' leases skip its studies
while another owner's keep leasing. Real servers with auth on, on SQLite and
PostgreSQL; the totals the database keeps (triggers of migration 0015) are checked
against the rows they count."""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Callable
from typing import Any

import httpx
import pytest
import sqlalchemy as sa

from adclient.testing.servers import ServerProcess, make_token
from tests.picky_template import JOINTED

pytestmark = pytest.mark.e2e

QUOTA = 3000
BOX = {"type": "box", "params": [{"name": "x", "low": 0, "high": 1}]}
TEMPLATE = {
    "type": "template",
    "template": (
        '<robot name="q" xmlns:xacro="http://www.ros.org/wiki/xacro"><link name="base">'
        '<visual><geometry><box size="${x} 0.1 0.1"/></geometry></visual></link>'
        f"{JOINTED}</robot>"
    ),
    "params": [{"name": "x", "low": 0.1, "high": 0.2}],
}


def study(name: str, *, task: bool = True, space: dict[str, Any] = BOX) -> dict[str, Any]:
    body: dict[str, Any] = {"name": name, "space": space, "proposer": {"name": "random"}}
    if task:
        body |= {"task": {"name": name, "external": True}, "max_trials": 20}
    return body


def client(server: ServerProcess, role: str, name: str = "") -> httpx.Client:
    token = make_token(server, role, name=name)
    return httpx.Client(
        base_url=server.url,
        headers={"Authorization": f"Bearer {token}", "X-Activedesign-Client": "test"},
        timeout=60,
        verify=False,
    )


def counted(url: str) -> tuple[dict[int, int], dict[int, int]]:
    """``(kept, recounted)``: each owner's bytes as ``owner_storage`` keeps them (owners
    storing nothing left out), and as the artifact and URDF rows add up to."""
    engine = sa.create_engine(url)
    with engine.connect() as connection:
        kept = dict(connection.execute(sa.text("SELECT owner_key, bytes FROM owner_storage")).all())
        owner_of = dict(
            connection.execute(
                sa.text(
                    "SELECT t.id, coalesce(s.owner_token_id, 0) FROM trials t "
                    "JOIN studies s ON s.id = t.study_id"
                )
            ).all()
        )
        recounted: dict[int, int] = defaultdict(int)
        for trial_id, size in connection.execute(sa.text("SELECT trial_id, size FROM artifacts")):
            recounted[owner_of[trial_id]] += size
        urdfs = connection.execute(sa.text("SELECT trial_id, urdf, error FROM trial_urdfs"))
        for trial_id, urdf, error in urdfs:
            recounted[owner_of[trial_id]] += len((urdf or "").encode()) + len(
                (error or "").encode()
            )
    engine.dispose()
    return {k: v for k, v in kept.items() if v}, {k: v for k, v in recounted.items() if v}


def test_an_owner_past_its_quota_stores_and_gets_nothing_new_while_others_lease(
    server_factory: Callable[..., ServerProcess],
) -> None:
    server = server_factory(AD_AUTH="true", AD_OWNER_STORAGE_BYTES=str(QUOTA))
    alice, bob = client(server, "user", "alice"), client(server, "user", "bob")
    worker = client(server, "worker")
    full = alice.post("/api/v1/studies", json=study("alice-managed")).json()
    asked = alice.post("/api/v1/studies", json=study("alice-asked", task=False)).json()
    bobs = bob.post("/api/v1/studies", json=study("bob-managed")).json()
    queue = alice.post(
        f"/api/v1/studies/{full['id']}/trials",
        json=[{"params": {"x": 0.1}}, {"params": {"x": 0.2}}],
    )
    assert queue.status_code == 201, queue.text
    both = {"worker_id": "w", "tasks": ["alice-managed", "bob-managed"]}
    job = worker.post("/api/v1/jobs/lease", json=both).json()
    assert job["study_id"] == full["id"]
    artifacts = f"/api/v1/trials/{job['trial_id']}/artifacts"

    assert worker.put(f"{artifacts}/a.bin?worker_id=w", content=bytes(2000)).status_code == 201
    refused = worker.put(f"{artifacts}/b.bin?worker_id=w", content=bytes(2000))
    assert refused.status_code == 413, refused.text
    detail = refused.json()["detail"]
    assert f"quota of {QUOTA} bytes" in detail and "AD_OWNER_STORAGE_BYTES" in detail, detail
    assert "'alice' store 2000 bytes" in detail, detail
    assert [a["name"] for a in worker.get(artifacts).json()] == ["a.bin"]
    assert worker.put(f"{artifacts}/b.bin?worker_id=w", content=bytes(1000)).status_code == 201

    # At the quota: nothing more of hers is stored, made or leased; bob's study leases.
    late = worker.put(f"{artifacts}/c.bin?worker_id=w", content=b"x")
    assert late.status_code == 413 and "AD_OWNER_STORAGE_BYTES" in late.json()["detail"]
    ask = alice.post(f"/api/v1/studies/{asked['id']}/ask", json={})
    assert ask.status_code == 409 and ask.json()["error"] == "over_quota", ask.text
    assert f"store {QUOTA} bytes" in ask.json()["detail"]
    enqueue = alice.post(f"/api/v1/studies/{asked['id']}/trials", json={"params": {"x": 0.5}})
    assert enqueue.status_code == 409 and "AD_OWNER_STORAGE_BYTES" in enqueue.text
    for _ in range(2):  # her queued trial is older, yet bob's study is served, twice
        other = worker.post("/api/v1/jobs/lease", json=both)
        assert other.status_code == 200 and other.json()["study_id"] == bobs["id"], other.text
    assert alice.get(f"/api/v1/studies/{asked['id']}/trials").json() == []

    # Replacing an artifact by a smaller one frees room: her queued trial leases again.
    assert worker.put(f"{artifacts}/b.bin?worker_id=w", content=bytes(500)).status_code == 201
    again = worker.post("/api/v1/jobs/lease", json=both).json()
    assert again["study_id"] == full["id"] and again["params"] == {"x": 0.2}
    kept, recounted = counted(server.database_url)
    assert kept == recounted and sum(kept.values()) == 2500, (kept, recounted)

    # A deleted study takes its bytes off its owner's.
    gone = alice.delete(f"/api/v1/studies/{full['id']}", params={"force": "true"})
    assert gone.status_code == 204, gone.text
    assert counted(server.database_url) == ({}, {})
    for api in (alice, bob, worker):
        api.close()


def test_a_template_studys_urdfs_count_toward_its_owners_quota(
    server_factory: Callable[..., ServerProcess],
) -> None:
    """Each trial's stored URDF is its owner's bytes: asks succeed until the owner
    stores the quota, then one is refused naming it; the totals are the URDFs' bytes."""
    server = server_factory(AD_AUTH="true", AD_OWNER_STORAGE_BYTES=str(QUOTA))
    with client(server, "user", "tina") as tina:
        made = tina.post("/api/v1/studies", json=study("tina", task=False, space=TEMPLATE))
        assert made.status_code == 201, made.text
        answers = []
        for _ in range(20):
            answers.append(tina.post(f"/api/v1/studies/{made.json()['id']}/ask", json={}))
            if answers[-1].status_code != 200:
                break
    *served, refused = answers
    assert len(served) >= 2 and all(answer.status_code == 200 for answer in served)
    assert refused.status_code == 409 and "AD_OWNER_STORAGE_BYTES" in refused.text, refused.text
    kept, recounted = counted(server.database_url)
    assert kept == recounted and next(iter(kept.values())) >= QUOTA, (kept, recounted)


def test_0015_counts_what_is_stored_keeps_counting_and_goes_back_down(
    empty_database_url: str,
) -> None:
    """Migrating counts the artifacts and URDFs already stored, by owner (the studies
    without one as owner 0); from then on the database's triggers keep the totals; going
    back down drops them."""
    from alembic import command

    from tests.service.test_migrations import _alembic

    config = _alembic(empty_database_url)
    command.upgrade(config, "0014")
    engine = sa.create_engine(empty_database_url)
    when = "'2024-01-01 00:00:00'"
    with engine.begin() as connection:
        for owner in (7, None):
            connection.execute(
                sa.text(
                    "INSERT INTO studies (name, direction, state, space, proposer, pruner,"
                    " max_attempts, n_trials, metadata, owner_token_id, created_at, updated_at)"
                    f" VALUES ('old', 'maximize', 'running', '{{}}', '{{}}', '{{}}', 3, 1, '{{}}',"
                    f" :owner, {when}, {when})"
                ),
                {"owner": owner},
            )
        connection.execute(
            sa.text(
                "INSERT INTO trials (study_id, number, state, vector, params, metrics, info,"
                f" attempts, created_at) SELECT id, 0, 'complete', '[]', '{{}}', '{{}}', '{{}}', 1,"
                f" {when} FROM studies"
            )
        )
        for trial_id, size in ((1, 100), (2, 50)):
            connection.execute(
                sa.text(
                    "INSERT INTO artifacts (trial_id, name, content_type, size, sha256, path,"
                    f" created_at) VALUES (:t, 'a', 'text/plain', :size, '', '', {when})"
                ),
                {"t": trial_id, "size": size},
            )
        connection.execute(
            sa.text(
                "INSERT INTO trial_urdfs (trial_id, urdf, error, created_at)"
                f" VALUES (1, 'ab\u00e9', NULL, {when})"
            )
        )
    command.upgrade(config, "head")
    assert counted(empty_database_url) == ({7: 104, 0: 50}, {7: 104, 0: 50})
    with engine.begin() as connection:
        connection.execute(sa.text("UPDATE artifacts SET size = 10 WHERE trial_id = 2"))
        connection.execute(sa.text("DELETE FROM trial_urdfs WHERE trial_id = 1"))
    assert counted(empty_database_url) == ({7: 100, 0: 10}, {7: 100, 0: 10})
    command.downgrade(config, "0014")
    with engine.connect() as connection:
        tables = set(sa.inspect(connection).get_table_names())
    engine.dispose()
    assert not {"owner_storage", "study_storage"} & tables
    command.upgrade(config, "head")
    assert counted(empty_database_url) == ({7: 100, 0: 10}, {7: 100, 0: 10})
