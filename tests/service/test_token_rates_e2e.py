"""Per-token request rates (adservice.rates) on a real server with auth on: a user's token
past its request or creation rate is answered 429 with Retry-After, naming the budget
and its settings, before its body is read, and stores nothing; another user's token, a
worker's and an admin's are not held back by it."""

from __future__ import annotations

import socket
from collections.abc import Iterator

import httpx
import pytest

from adclient.testing.neighbours import client
from adclient.testing.servers import ServerProcess, make_token

pytestmark = pytest.mark.e2e

RATES = {
    "AD_TOKEN_REQUESTS_PER_SECOND": "0.5",
    "AD_TOKEN_REQUEST_BURST": "8",
    "AD_TOKEN_CREATIONS_PER_MINUTE": "1",
    "AD_TOKEN_CREATION_BURST": "2",
}
"""Slow refills, so that what a test sends quickly is past the burst on any machine."""
BOX = {
    "name": "rated",
    "space": {"type": "box", "params": [{"name": "x", "low": 0, "high": 1}]},
    "proposer": {"name": "random"},
}


@pytest.fixture
def rated(server_factory: object) -> Iterator[ServerProcess]:
    yield server_factory(AD_AUTH="1", **RATES)  # type: ignore[operator]


def as_token(server: ServerProcess, role: str, name: str) -> httpx.Client:
    return client(server.url, make_token(server, role, name=name))


def test_a_users_token_past_its_rates_is_answered_429_naming_them(rated: ServerProcess) -> None:
    with (
        as_token(rated, "user", "alice") as alice,
        as_token(rated, "user", "bob") as bob,
        as_token(rated, "worker", "shared") as worker,
        as_token(rated, "admin", "root") as admin,
    ):
        created = [alice.post("/api/v1/studies", json=BOX) for _ in range(3)]
        assert [answer.status_code for answer in created] == [201, 201, 429], created[-1].text
        refused = created[-1]
        assert refused.json()["error"] == "rate_limited"
        assert (
            "token 'alice' may send 1 study creations a minute in bursts of 2"
            in (refused.json()["detail"])
        )
        assert "AD_TOKEN_CREATIONS_PER_MINUTE" in refused.json()["detail"]
        assert int(refused.headers["Retry-After"]) >= 1
        # the requests' bucket (8) has 5 left after the three creations
        reads = [alice.get("/api/v1/studies").status_code for _ in range(8)]
        assert reads[:5] == [200] * 5 and 429 in reads, reads
        limited = alice.get("/api/v1/studies")
        assert limited.status_code == 429
        assert "AD_TOKEN_REQUESTS_PER_SECOND" in limited.json()["detail"]

        # nothing stored by the refused creation; others are not held back
        studies = admin.get("/api/v1/studies").json()
        assert [study["name"] for study in studies] == ["rated", "rated"]
        assert [bob.get("/api/v1/studies").status_code for _ in range(8)] == [200] * 8
        leases = [
            worker.post("/api/v1/jobs/lease", json={"worker_id": "w"}).status_code
            for _ in range(20)
        ]
        assert set(leases) == {204}, leases
        assert {admin.get("/api/v1/studies").status_code for _ in range(20)} == {200}


def test_a_limited_creation_is_refused_before_its_body_is_read(rated: ServerProcess) -> None:
    """A creation past the rate that declares a large body and sends none of it is
    answered at once (never after the body's deadline), and the connection is closed."""
    token = make_token(rated, "user", name="carol")
    with httpx.Client(
        base_url=rated.url, headers={"Authorization": f"Bearer {token}"}, verify=False
    ) as carol:
        assert [carol.post("/api/v1/studies", json=BOX).status_code for _ in range(2)] == [201] * 2
    request = (
        "POST /api/v1/studies HTTP/1.1\r\nHost: 127.0.0.1\r\n"
        f"Authorization: Bearer {token}\r\nContent-Type: application/json\r\n"
        "Content-Length: 900000\r\n\r\n"
    ).encode()
    with socket.create_connection(("127.0.0.1", rated.port), timeout=30) as connection:
        connection.sendall(request)
        answer = connection.recv(65536).decode("latin-1")
        assert connection.recv(65536) == b""  # closed: the body is never read
    assert answer.startswith("HTTP/1.1 429"), answer
    assert "connection: close" in answer.lower()
