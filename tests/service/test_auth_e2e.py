"""Bearer tokens with roles, against a real server with auth on."""

from __future__ import annotations

import os
import subprocess
from collections.abc import Callable
from pathlib import Path

import httpx
import pytest

from adclient.testing.forked import run_adserver
from adclient.testing.servers import ADSERVER, ServerProcess, make_token

pytestmark = pytest.mark.e2e

BOX_STUDY = {
    "name": "secured",
    "space": {"type": "box", "params": [{"name": "x", "low": 0, "high": 1}]},
    "proposer": {"name": "random"},
    "task": {"name": "noop", "external": True},
    "max_trials": 5,
}


@pytest.fixture
def secured(server_factory: Callable[..., ServerProcess]) -> ServerProcess:
    return server_factory(AD_AUTH="true")


def client(server: ServerProcess, token: str | None = None) -> httpx.Client:
    headers = {"Authorization": f"Bearer {token}"} if token else {}
    return httpx.Client(base_url=server.url, headers=headers, timeout=30, verify=False)


def test_roles_gate_every_kind_of_call(secured: ServerProcess) -> None:
    admin, worker, reader, user = (
        make_token(secured, role) for role in ("admin", "worker", "reader", "user")
    )
    with client(secured) as anonymous:
        missing = anonymous.get("/api/v1/studies")
        assert missing.status_code == 401 and missing.headers["WWW-Authenticate"] == "Bearer"
        assert anonymous.get("/healthz").status_code == 200
    with client(secured, "adt_not-a-real-token") as forged:
        assert forged.get("/api/v1/studies").status_code == 401
    with client(secured, reader) as as_reader:
        denied = as_reader.post("/api/v1/studies", json=BOX_STUDY)
        assert denied.status_code == 403 and "user role" in denied.json()["detail"]
        assert as_reader.post("/api/v1/jobs/lease", json={"worker_id": "r"}).status_code == 403
    with client(secured, worker) as as_worker:
        assert as_worker.post("/api/v1/studies", json=BOX_STUDY).status_code == 403
    with client(secured, user) as as_user:
        study = as_user.post("/api/v1/studies", json=BOX_STUDY)
        assert study.status_code == 201
    with client(secured, admin) as as_admin:
        assert as_admin.post("/api/v1/studies", json=BOX_STUDY).status_code == 201
    with client(secured, reader) as as_reader:
        assert as_reader.get(f"/api/v1/studies/{study.json()['id']}").status_code == 200
    with client(secured, worker) as as_worker:
        job = as_worker.post("/api/v1/jobs/lease", json={"worker_id": "w1"}).json()
        tell_url = f"/api/v1/trials/{job['trial_id']}/tell"
        anonymous_tell = as_worker.post(tell_url, json={"value": 1.0})
        assert anonymous_tell.status_code == 403 and "worker_id" in anonymous_tell.json()["detail"]
        assert as_worker.post(tell_url, json={"value": 1.0, "worker_id": "w2"}).status_code == 409
        assert as_worker.post(tell_url, json={"value": 1.0, "worker_id": "w1"}).status_code == 200


def test_no_token_is_401_before_the_body_is_read(secured: ServerProcess) -> None:
    """A caller without a token learns nothing about its body: 401, not 422."""
    with client(secured) as anonymous:
        for method, path in (("POST", "/api/v1/studies"), ("POST", "/api/v1/trials/1/tell")):
            answer = anonymous.request(
                method, path, content=b"{not json", headers={"Content-Type": "application/json"}
            )
            assert answer.status_code == 401, (path, answer.text)


def token_command(server: ServerProcess, output: Path, *argv: str) -> str:
    """``adserver token ARGV`` on the server's database, as an operator runs it (forked,
    as the harness starts the server itself); what it printed, having exited 0."""
    argv = ("token", *argv, "--database-url", server.database_url)
    code = run_adserver(list(argv), env=os.environ, cwd=server.workdir, output=output)
    printed = output.read_text()
    output.unlink()
    assert code == 0, printed
    return printed


def test_revoked_token_stops_working(secured: ServerProcess, tmp_path: Path) -> None:
    reader = make_token(secured, "reader")
    with client(secured, reader) as as_reader:
        assert as_reader.get("/api/v1/studies").status_code == 200
    listed = token_command(secured, tmp_path / "out", "list")
    token_id = listed.split()[0]
    token_command(secured, tmp_path / "out", "revoke", token_id)
    secured.restart()  # no cached answer survives a restart; within one process it lasts 5 s
    with client(secured, reader) as as_reader:
        assert as_reader.get("/api/v1/studies").status_code == 401


def test_non_loopback_without_auth_is_refused(tmp_path: object) -> None:
    done = subprocess.run(
        [
            str(ADSERVER),
            "--host",
            "0.0.0.0",
            "--port",
            "1",
            "--database-url",
            f"sqlite:///{tmp_path}/x.db",
        ],
        capture_output=True,
        text=True,
        timeout=60,
        env={"AD_AUTH": "false", "PATH": ""},
    )
    assert done.returncode == 2
    assert "refusing" in done.stderr and "--insecure" in done.stderr


def test_unknown_role_is_refused(tmp_path: object) -> None:
    done = subprocess.run(
        [
            str(ADSERVER),
            "token",
            "create",
            "--role",
            "owner",
            "--database-url",
            f"sqlite:///{tmp_path}/x.db",
        ],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert done.returncode == 2 and "unknown role" in done.stderr
