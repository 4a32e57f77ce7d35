"""``/api/v1/session`` answers only the server's own pages (issue 36), against a real
``adserver`` with auth on: a request whose ``Origin`` is another site's, or whose
``Sec-Fetch-Site`` says another site sent it, learns no CSRF token and signs no one in
or out (403); the server's own origin, ``AD_PUBLIC_URL``'s, and clients that send
neither header (the SDK, curl) are answered as before."""

from __future__ import annotations

from collections.abc import Callable

import httpx
import pytest

from adclient.testing.servers import ServerProcess, free_port, make_token

pytestmark = pytest.mark.e2e

PUBLIC = "https://design.example.org"


@pytest.mark.parametrize("database", ["sqlite"])  # a check of headers, not of storage
def test_the_session_answers_only_the_server_s_own_pages(
    server_factory: Callable[..., ServerProcess],
) -> None:
    server = server_factory(AD_AUTH="true", AD_PUBLIC_URL=PUBLIC)
    token = make_token(server, "user", name="dana")
    own = f"http://127.0.0.1:{server.port}"
    with httpx.Client(base_url=server.url, timeout=30) as browser:
        signed = browser.post("/api/v1/session", json={"token": token}, headers={"Origin": own})
        assert signed.status_code == 200, signed.text
        csrf = signed.json()["csrf_token"]
        assert csrf

        def session(**headers: str) -> httpx.Response:
            return browser.get("/api/v1/session", headers=headers)

        answered = [
            {},  # the SDK, curl, an old browser's same-origin GET
            {"Origin": own},
            {"Origin": own.replace("127.0.0.1", "localhost"), "Host": f"localhost:{server.port}"},
            {"Origin": PUBLIC, "Host": "design.example.org"},  # behind a TLS proxy
            {"Origin": f"{PUBLIC}:443"},
            {"Sec-Fetch-Site": "same-origin", "Origin": own},
            {"Sec-Fetch-Site": "none"},  # typed in the address bar
        ]
        for headers in answered:
            answer = session(**headers)
            assert answer.status_code == 200, (headers, answer.text)
            assert answer.json()["csrf_token"] == csrf, headers

        refused = [
            {"Origin": f"http://127.0.0.1:{free_port()}"},  # another port: another origin
            {"Origin": f"https://127.0.0.1:{server.port}"},  # another scheme
            {"Origin": "https://evil.example"},
            {"Origin": "null"},  # a sandboxed frame, a file
            {"Origin": "http://design.example.org"},
            {"Origin": "not an origin"},
            {"Sec-Fetch-Site": "cross-site"},
            {"Sec-Fetch-Site": "same-site"},  # a sibling host's page is not the server's
            {"Sec-Fetch-Site": "cross-site", "Origin": own},
        ]
        for headers in refused:
            answer = session(**headers)
            assert answer.status_code == 403, (headers, answer.text)
            assert answer.json()["error"] == "forbidden", headers
            assert "own pages" in answer.json()["detail"], headers
            assert csrf not in answer.text, headers

        evil = {"Origin": "https://evil.example"}
        other = browser.post("/api/v1/session", json={"token": token}, headers=evil)
        assert other.status_code == 403 and "set-cookie" not in other.headers
        gone = browser.delete("/api/v1/session", headers={**evil, "X-CSRF-Token": csrf})
        assert gone.status_code == 403
        assert session().json()["signed_in"]  # the cross-site sign-out ended nothing
