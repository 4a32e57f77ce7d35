"""Leases belong to tokens, studies to their creators, artifacts are inert: a real server
with auth on, real tokens made by ``adserver token create``."""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator
from typing import Any

import httpx
import pytest

from adclient.testing.servers import ServerProcess, make_token

pytestmark = [pytest.mark.e2e, pytest.mark.xdist_group("ownership")]

MANAGED = {
    "name": "managed",
    "space": {"type": "box", "params": [{"name": "x", "low": 0, "high": 1}]},
    "proposer": {"name": "random"},
    "task": {"name": "noop", "external": True},
    "max_trials": 20,
}
ASKED = {**MANAGED, "name": "asked", "task": None}
PNG = b"\x89PNG\r\n\x1a\n" + bytes(64)
SCRIPT_SVG = b'<svg xmlns="http://www.w3.org/2000/svg"><script>alert(1)</script></svg>'


@pytest.fixture(scope="module")
def token(secured: ServerProcess) -> Callable[..., str]:
    """``token(role, name="")``: a token of the shared server, made by ``adserver token
    create`` once per role and name, for every test that asks for it."""
    made: dict[tuple[str, str], str] = {}

    def of(role: str, name: str = "") -> str:
        if (role, name) not in made:
            made[role, name] = make_token(secured, role, name=name)
        return made[role, name]

    return of


def managed(task: str) -> dict[str, Any]:
    """A managed study of its own ``task``, so that leasing ``[task]`` takes its jobs and
    no other test's on a shared server."""
    return {**MANAGED, "task": {"name": task, "external": True}}


def as_token(server: ServerProcess, token: str) -> httpx.Client:
    return httpx.Client(
        base_url=server.url,
        headers={"Authorization": f"Bearer {token}", "X-Activedesign-Client": "test"},
        timeout=30,
        verify=False,
    )


def trial_state(api: httpx.Client, trial_id: int) -> dict:
    answer = api.get(f"/api/v1/trials/{trial_id}")
    assert answer.status_code == 200
    return answer.json()


def test_only_the_leasing_token_acts_on_a_trial(
    secured: ServerProcess, token: Callable[..., str]
) -> None:
    admin = as_token(secured, token("admin"))
    first = as_token(secured, token("worker"))
    second = as_token(secured, token("worker", name="second"))
    assert admin.post("/api/v1/studies", json=managed("leasing-token")).status_code == 201
    lease = {"worker_id": "a", "tasks": ["leasing-token"]}
    job = first.post("/api/v1/jobs/lease", json=lease).json()
    trial = f"/api/v1/trials/{job['trial_id']}"
    before = trial_state(admin, job["trial_id"])

    # The second token claims the first's worker id: refused on every route, nothing changes.
    impostor = {"worker_id": "a"}
    for path, body in (
        ("/heartbeat", impostor),
        ("/release", impostor),
        ("/tell", {**impostor, "value": 9.0}),
        ("/tell", {**impostor, "state": "failed"}),
    ):
        answer = second.post(trial + path, json=body)
        assert answer.status_code == 403, (path, answer.text)
        assert "another token" in answer.json()["detail"]
    upload = second.put(trial + "/artifacts/robot.png?worker_id=a", content=PNG)
    assert upload.status_code == 403
    after = trial_state(admin, job["trial_id"])
    assert after == before
    assert admin.get(trial + "/artifacts").json() == []

    # The holder still can do all of it.
    assert first.post(trial + "/heartbeat", json={"worker_id": "a"}).status_code == 200
    stored = first.put(trial + "/artifacts/robot.png?worker_id=a", content=PNG)
    assert stored.status_code == 201
    told = first.post(trial + "/tell", json={"worker_id": "a", "value": 0.5})
    assert told.status_code == 200 and told.json()["value"] == 0.5
    # ... and after the tell, artifacts are refused: the trial is finished.
    late = first.put(trial + "/artifacts/late.json?worker_id=a", content=b"{}")
    assert late.status_code == 409 and "complete" in late.json()["detail"]


def test_an_admin_releases_or_fails_any_trial(
    secured: ServerProcess, token: Callable[..., str]
) -> None:
    admin = as_token(secured, token("admin"))
    worker = as_token(secured, token("worker"))
    admin.post("/api/v1/studies", json=managed("admin-releases"))
    lease = {"worker_id": "w", "tasks": ["admin-releases"]}
    held = worker.post("/api/v1/jobs/lease", json=lease).json()
    released = admin.post(f"/api/v1/trials/{held['trial_id']}/release", json={})
    assert released.status_code == 200 and released.json()["state"] == "queued"
    # A worker must name itself to release.
    again = worker.post("/api/v1/jobs/lease", json=lease).json()
    assert again["trial_id"] == held["trial_id"]
    unnamed = worker.post(f"/api/v1/trials/{again['trial_id']}/release", json={})
    assert unnamed.status_code == 403
    failed = admin.post(
        f"/api/v1/trials/{again['trial_id']}/tell", json={"state": "failed", "message": "bad"}
    )
    assert failed.status_code == 200 and failed.json()["state"] == "failed"
    late = worker.post(
        f"/api/v1/trials/{again['trial_id']}/tell", json={"worker_id": "w", "value": 1}
    )
    assert late.status_code == 409


def test_users_manage_only_their_own_studies(
    secured: ServerProcess, token: Callable[..., str]
) -> None:
    alice = as_token(secured, token("user", name="alice"))
    bob = as_token(secured, token("user", name="bob"))
    admin = as_token(secured, token("admin"))
    reader = as_token(secured, token("reader"))
    study = alice.post("/api/v1/studies", json=ASKED).json()
    assert study["created_by"] == "alice"
    url = f"/api/v1/studies/{study['id']}"
    (trial,) = alice.post(url + "/ask", json={"count": 1}).json()["trials"]

    for api in (bob, reader):
        assert api.get(url).status_code == 200  # everyone with a token reads
        assert api.get(url + "/trials").status_code == 200
    for path, body in ((url + "/ask", {"count": 1}), (url + "/stop", {})):
        denied = bob.post(path, json=body)
        assert denied.status_code == 403 and "alice" in denied.json()["detail"], denied.text
    denied_tell = bob.post(f"/api/v1/trials/{trial['id']}/tell", json={"value": 1.0})
    assert denied_tell.status_code == 403
    assert (
        bob.put(f"/api/v1/trials/{trial['id']}/artifacts/x.json", content=b"{}").status_code == 403
    )
    assert reader.post(url + "/stop", json={}).status_code == 403
    unchanged = alice.get(url).json()
    assert unchanged["state"] == "running" and unchanged["n_trials"] == 1
    assert unchanged["n_complete"] == 0

    # The owner asks, uploads and tells its own; an admin stops anyone's.
    assert (
        alice.put(f"/api/v1/trials/{trial['id']}/artifacts/x.json", content=b"{}").status_code
        == 201
    )
    assert alice.post(f"/api/v1/trials/{trial['id']}/tell", json={"value": 1.0}).status_code == 200
    assert alice.post(url + "/ask", json={"count": 1}).status_code == 200
    # Bob's own study is his.
    own = bob.post("/api/v1/studies", json=ASKED).json()
    assert bob.post(f"/api/v1/studies/{own['id']}/ask", json={"count": 1}).status_code == 200
    stopped = admin.post(url + "/stop", json={})
    assert stopped.status_code == 200 and stopped.json()["state"] == "stopped"


def test_artifact_uploads_need_the_lease_and_fit_the_quota(
    server_factory: Callable[..., ServerProcess],
) -> None:
    secured = server_factory(AD_AUTH="true", AD_MAX_ARTIFACTS_PER_TRIAL="3")
    admin = as_token(secured, make_token(secured, "admin"))
    worker = as_token(secured, make_token(secured, "worker"))
    admin.post("/api/v1/studies", json=MANAGED)
    job = worker.post("/api/v1/jobs/lease", json={"worker_id": "w"}).json()
    base = f"/api/v1/trials/{job['trial_id']}/artifacts"
    queued_trial = job["trial_id"] + 1000
    assert (
        worker.put(f"/api/v1/trials/{queued_trial}/artifacts/a.json", content=b"{}").status_code
        == 404
    )
    assert worker.put(base + "/a.json?worker_id=other", content=b"{}").status_code == 409
    for name in ("a.json", "b.json", "c.json"):
        assert worker.put(f"{base}/{name}?worker_id=w", content=b"{}").status_code == 201
    assert worker.put(base + "/a.json?worker_id=w", content=b"[]").status_code == 201  # replaces
    over = worker.put(base + "/d.json?worker_id=w", content=b"{}")
    assert over.status_code == 413 and "3 artifacts" in over.json()["detail"]
    assert sorted(a["name"] for a in admin.get(base).json()) == ["a.json", "b.json", "c.json"]


def test_artifacts_are_served_inert(secured: ServerProcess, token: Callable[..., str]) -> None:
    admin = as_token(secured, token("admin"))
    worker = as_token(secured, token("worker"))
    admin.post("/api/v1/studies", json=managed("served-inert"))
    lease = {"worker_id": "w", "tasks": ["served-inert"]}
    job = worker.post("/api/v1/jobs/lease", json=lease).json()
    base = f"/api/v1/trials/{job['trial_id']}/artifacts"
    uploads = {
        "robot.png": (SCRIPT_SVG, "image/svg+xml"),
        "page.html": (b"<script>alert(1)</script>", "text/html"),
        "real.png": (PNG, "text/html"),
        "curve.json": (b"[1, 2]", "application/json"),
    }
    for name, (data, declared) in uploads.items():
        answer = worker.put(
            f"{base}/{name}?worker_id=w", content=data, headers={"Content-Type": declared}
        )
        assert answer.status_code == 201
    served = {name: admin.get(f"{base}/{name}") for name in uploads}
    for name, answer in served.items():
        assert answer.headers["x-content-type-options"] == "nosniff", name
        assert answer.headers["content-security-policy"].startswith("sandbox"), name
    for name in ("robot.png", "page.html"):  # script, whatever its name or declared type
        assert served[name].headers["content-type"] == "application/octet-stream"
        assert served[name].headers["content-disposition"].startswith("attachment")
    assert served["real.png"].headers["content-type"] == "image/png"  # from its bytes
    assert served["real.png"].headers["content-disposition"].startswith("inline")
    assert served["curve.json"].headers["content-type"].startswith("application/json")
    assert served["curve.json"].headers["content-disposition"].startswith("attachment")


def test_dashboard_sign_in_is_a_cookie_session_with_csrf(
    secured: ServerProcess, token: Callable[..., str]
) -> None:
    carol = token("user", name="carol")
    with httpx.Client(base_url=secured.url, timeout=30, verify=False) as browser:
        assert browser.get("/api/v1/session").json() == {
            "auth": True,
            "signed_in": False,
            "role": None,
            "name": None,
            "csrf_token": None,
        }
        assert browser.post("/api/v1/session", json={"token": "adt_wrong"}).status_code == 401
        signed = browser.post("/api/v1/session", json={"token": carol})
        assert signed.status_code == 200
        cookie = signed.headers["set-cookie"].lower()
        assert "httponly" in cookie and "samesite=strict" in cookie and carol.lower() not in cookie
        info = signed.json()
        assert info["signed_in"] and info["role"] == "user" and info["name"] == "carol"
        assert browser.get("/api/v1/studies").status_code == 200  # the cookie authenticates
        # A change with the cookie needs the CSRF token.
        no_csrf = browser.post("/api/v1/studies", json=MANAGED)
        assert no_csrf.status_code == 403 and "CSRF" in no_csrf.json()["detail"]
        wrong = browser.post("/api/v1/studies", json=MANAGED, headers={"X-CSRF-Token": "x"})
        assert wrong.status_code == 403
        made = browser.post(
            "/api/v1/studies", json=MANAGED, headers={"X-CSRF-Token": info["csrf_token"]}
        )
        assert made.status_code == 201 and made.json()["created_by"] == "carol"
        assert browser.get("/api/v1/session").json()["csrf_token"] == info["csrf_token"]
        out = browser.delete("/api/v1/session", headers={"X-CSRF-Token": info["csrf_token"]})
        assert out.status_code == 204
        browser.cookies.clear()
    # The old cookie is dead on the server too, not only forgotten by the browser.
    old = signed.cookies.get("ad_session")
    with httpx.Client(
        base_url=secured.url, timeout=30, cookies={"ad_session": old}, verify=False
    ) as replay:
        assert replay.get("/api/v1/studies").status_code == 401


def test_a_simple_cross_site_request_changes_nothing(shared_server: ServerProcess) -> None:
    """Auth off (loopback): what a page on another origin can send unasked, a form post or
    a no-cors fetch, has neither a JSON type nor a custom header, and is refused."""
    with httpx.Client(base_url=shared_server.url, timeout=30, verify=False) as browser_like:
        study = browser_like.post("/api/v1/studies", json=ASKED).json()  # JSON: allowed
        url = f"/api/v1/studies/{study['id']}"
        for headers, body in (
            ({}, b""),
            ({"Content-Type": "text/plain"}, b'{"count": 1}'),
            ({"Content-Type": "application/x-www-form-urlencoded"}, b"count=1"),
            ({"Content-Type": "multipart/form-data; boundary=x"}, b"--x--"),
        ):
            for path in ("/stop", "/ask"):
                refused = browser_like.post(url + path, content=body, headers=headers)
                assert refused.status_code == 415, (path, headers, refused.text)
        assert browser_like.get(url).json()["state"] == "running"
        assert browser_like.get(url).json()["n_trials"] == 0
        # DELETE, PUT and PATCH are preflighted by a browser: they pass as a REST
        # client sends them, to be refused by the route for what they are.
        patched = browser_like.patch(url, content=b"x=1", headers={"Content-Type": "text/plain"})
        assert patched.status_code == 422, patched.text
        # The SDK's header, or JSON, is what a client sends.
        stopped = browser_like.post(url + "/stop", headers={"X-Activedesign-Client": "x"})
        assert stopped.status_code == 200 and stopped.json()["state"] == "stopped"


def test_every_answer_carries_security_headers(shared_server: ServerProcess) -> None:
    with httpx.Client(base_url=shared_server.url, timeout=30, verify=False) as http:
        for path in ("/", "/index.html", "/healthz", "/docs"):  # pages
            answer = http.get(path)
            assert answer.headers["x-content-type-options"] == "nosniff", path
            assert answer.headers["x-frame-options"] == "DENY", path
            policy = answer.headers["content-security-policy"]
            assert "frame-ancestors 'none'" in policy and "script-src 'self'" in policy, path
            assert "unsafe-inline" not in policy.split("script-src")[1].split(";")[0]
        for path in ("/api/v1/studies", "/api/v1/nowhere"):  # JSON: runs and embeds nothing
            answer = http.get(path)
            assert answer.headers["x-content-type-options"] == "nosniff", path
            policy = answer.headers["content-security-policy"]
            assert policy == "default-src 'none'; frame-ancestors 'none'", path
            assert "access-control-allow-origin" not in answer.headers  # CORS off
        preflight = http.options(
            "/api/v1/studies",
            headers={"Origin": "https://evil.example", "Access-Control-Request-Method": "POST"},
        )
        assert "access-control-allow-origin" not in preflight.headers


def test_host_header_must_name_the_server(server_factory: Callable[..., ServerProcess]) -> None:
    """DNS rebinding: a page whose name now points at 127.0.0.1 still sends its own name."""
    server = server_factory(AD_PUBLIC_URL="https://design.example.org")
    with httpx.Client(base_url=server.url, timeout=30, verify=False) as http:
        for host in (f"127.0.0.1:{server.port}", "localhost", "design.example.org"):
            assert http.get("/api/v1/studies", headers={"Host": host}).status_code == 200, host
        for host in ("attacker.example", f"rebound.attacker.example:{server.port}"):
            refused = http.post("/api/v1/studies", json=ASKED, headers={"Host": host})
            assert refused.status_code == 400, host
        assert http.get("/api/v1/studies").json() == []


def test_an_upload_refused_at_its_end_leaves_the_artifact_as_it_was(
    shared_server: ServerProcess,
) -> None:
    """The lease is lost while a new version streams in: the old version stays served,
    and once a version is replaced its file is gone from disk."""
    http = httpx.Client(
        base_url=shared_server.url, timeout=30, headers={"X-Activedesign-Client": "t"}, verify=False
    )
    study = http.post("/api/v1/studies", json=managed("refused-upload")).json()
    lease = {"worker_id": "w", "tasks": ["refused-upload"]}
    job = http.post("/api/v1/jobs/lease", json=lease).json()
    url = f"/api/v1/trials/{job['trial_id']}/artifacts/curve.json?worker_id=w"
    assert http.put(url, content=b"[1]").status_code == 201
    assert http.put(url, content=b"[1, 2]").status_code == 201  # replaces [1]
    folder = shared_server.artifact_dir / str(study["id"])  # this study's artifacts
    files = list(folder.rglob("curve.json.*"))
    assert [f.read_bytes() for f in files] == [b"[1, 2]"]

    halfway = threading.Event()
    go_on = threading.Event()

    def slow_body() -> Iterator[bytes]:
        yield b"[1, 2, "
        halfway.set()
        go_on.wait(30)
        yield b"3]"

    answer: list[httpx.Response] = []
    upload = threading.Thread(target=lambda: answer.append(http.put(url, content=slow_body())))
    upload.start()
    assert halfway.wait(30)
    released = http.post(f"/api/v1/trials/{job['trial_id']}/release", json={})
    assert released.status_code == 200  # auth off: an admin takes the trial back
    go_on.set()
    upload.join(30)
    assert answer[0].status_code == 409, answer[0].text
    assert http.get(url.split("?")[0]).content == b"[1, 2]"
    files = list(folder.rglob("curve.json.*"))
    assert [f.read_bytes() for f in files] == [b"[1, 2]"]
    http.close()
