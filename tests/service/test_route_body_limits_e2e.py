"""Body limits by route (issue 58): only the artifact upload route takes the artifact
body limit, every other path the plain one, however it is spelt; and a caller whose
role a change's route does not admit is refused before its body is read. A real server
with auth on."""

from __future__ import annotations

import socket
from collections.abc import Iterator

import httpx
import pytest
from fastapi.routing import iter_route_contexts

from adclient.testing.servers import ServerProcess, make_token
from adservice.app import create_app
from adservice.limits import ARTIFACT_UPLOAD_PATH
from adservice.settings import Settings

pytestmark = pytest.mark.e2e

BODY_TIMEOUT = 3.0
PATIENCE = 60.0
"""Socket timeouts: only stop a broken build from hanging."""
PAST_PLAIN_LIMIT = 1_500_000
"""Over AD_MAX_BODY_BYTES' default (1 MB), under AD_MAX_ARTIFACT_BYTES' (16 MB)."""


@pytest.fixture(scope="module")
def secured(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    workdir = tmp_path_factory.mktemp("route-limits")
    server = ServerProcess(
        database_url=f"sqlite:///{workdir / 'studies.db'}",
        workdir=workdir,
        env={"AD_AUTH": "true", "AD_BODY_TIMEOUT": str(BODY_TIMEOUT)},
    )
    yield server.start()
    server.stop()


def api(server: ServerProcess, token: str) -> httpx.Client:
    return httpx.Client(
        base_url=server.url,
        headers={"Authorization": f"Bearer {token}", "X-Activedesign-Client": "test"},
        timeout=PATIENCE,
        verify=False,
    )


def answer_to_part_of_a_body(
    server: ServerProcess, method: str, path: str, token: str, declared: int
) -> bytes:
    """What the server answers a request that declares a ``declared``-byte body and
    sends only its first kilobyte, then waits: the status line and headers."""
    with socket.create_connection(("127.0.0.1", server.port)) as sock:
        sock.settimeout(PATIENCE)
        head = (
            f"{method} {path} HTTP/1.1\r\nHost: 127.0.0.1\r\n"
            f"Authorization: Bearer {token}\r\nContent-Type: application/json\r\n"
            f"Content-Length: {declared}\r\n\r\n"
        )
        sock.sendall(head.encode() + b"[" + b" " * 1023)
        received = b""
        while b"\r\n\r\n" not in received and (chunk := sock.recv(65_536)):
            received += chunk
    return received


def test_the_artifact_limit_is_the_upload_routes_alone(secured: ServerProcess) -> None:
    """The issue's probe: a reader's body to ``/api/v1/trials/artifacts/tell`` took the
    16 MB artifact limit (any path holding ``/artifacts/``) and was read before its
    403. Now any path but the upload route takes the 1 MB limit, while an upload of the
    same size to a trial's artifact is stored."""
    reader = api(secured, make_token(secured, "reader"))
    body = b"{" + b" " * (PAST_PLAIN_LIMIT - 2) + b"}"
    for method, path in (
        ("POST", "/api/v1/trials/artifacts/tell"),
        ("POST", "/api/v1/trials/1/artifacts/x/tell"),
        ("PUT", "/api/v1/trials/1/artifacts/x/y"),
    ):
        refused = reader.request(method, path, content=body)
        assert refused.status_code == 413, (path, refused.text)
        assert "AD_MAX_BODY_BYTES" in refused.json()["detail"]
    admin, worker = (
        api(secured, make_token(secured, "admin")),
        api(secured, make_token(secured, "worker")),
    )
    study = {
        "name": "uploads",
        "space": {"type": "box", "params": [{"name": "x", "low": 0, "high": 1}]},
        "proposer": {"name": "random"},
        "task": {"name": "route-limits", "external": True},
        "max_trials": 2,
    }
    assert admin.post("/api/v1/studies", json=study).status_code == 201
    job = worker.post("/api/v1/jobs/lease", json={"worker_id": "w", "tasks": ["route-limits"]})
    upload = worker.put(
        f"/api/v1/trials/{job.json()['trial_id']}/artifacts/big.bin?worker_id=w", content=body
    )
    assert upload.status_code == 201 and upload.json()["size"] == PAST_PLAIN_LIMIT, upload.text
    for client in (reader, admin, worker):
        client.close()


@pytest.mark.parametrize(
    ("role", "method", "path", "needed"),
    [
        ("reader", "POST", "/api/v1/trials/1/tell", "worker"),
        ("reader", "PUT", "/api/v1/trials/1/artifacts/robot.png", "worker"),
        ("worker", "POST", "/api/v1/studies", "user"),
        ("worker", "POST", "/api/v1/studies/1/ask", "user"),
    ],
)
def test_a_role_the_route_refuses_is_answered_before_its_body(
    secured: ServerProcess, role: str, method: str, path: str, needed: str
) -> None:
    """The 403 comes while the body is still being sent (the server would otherwise
    wait for it and answer 408 after AD_BODY_TIMEOUT), and closes the connection."""
    answer = answer_to_part_of_a_body(secured, method, path, make_token(secured, role), 500_000)
    status, _, rest = answer.partition(b"\r\n")
    assert status == b"HTTP/1.1 403 Forbidden", answer
    assert b"connection: close" in rest.lower(), answer


def test_the_artifact_limit_names_the_apps_one_put_route() -> None:
    """The limit's path is the upload route's path; the app's other PUTs, the notes
    (a few kB of text), are not that path and take the plain limit."""
    routes = iter_route_contexts(create_app(Settings(database_url="sqlite://")).router.routes)
    puts = [route.path for route in routes if "PUT" in (route.methods or ())]
    assert ARTIFACT_UPLOAD_PATH in puts
    assert set(puts) == {
        ARTIFACT_UPLOAD_PATH,
        "/api/v1/studies/{study_id}/note",
        "/api/v1/trials/{trial_id}/note",
        "/api/{rest:path}",  # the unknown paths' 404
    }
