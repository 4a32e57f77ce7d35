"""Crashes: a server SIGKILLed mid-stream keeps every acknowledged tell; a broken upload
is never served as a complete artifact."""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Callable
from typing import Any

import httpx
import pytest

from adclient.testing.servers import SDK_HEADERS, ServerProcess

pytestmark = [pytest.mark.e2e, pytest.mark.xdist_group("crash-safety")]

BOX = {"type": "box", "params": [{"name": "x", "low": 0.0, "high": 1.0}]}


def one_trial(http: httpx.Client) -> dict[str, Any]:
    """A fresh study with one running trial."""
    study = http.post(
        "/api/v1/studies", json={"name": "art", "space": BOX, "proposer": {"name": "random"}}
    ).json()
    return http.post(f"/api/v1/studies/{study['id']}/ask", json={"count": 1}).json()["trials"][0]


def test_acknowledged_tells_survive_sigkill(server_factory: Callable[..., ServerProcess]) -> None:
    server = server_factory()
    with httpx.Client(base_url=server.url, timeout=10, headers=SDK_HEADERS, verify=False) as http:
        study = http.post(
            "/api/v1/studies", json={"name": "crash", "space": BOX, "proposer": {"name": "random"}}
        ).json()
        trials = http.post(f"/api/v1/studies/{study['id']}/ask", json={"count": 64}).json()
        trials = (
            trials["trials"]
            + http.post(f"/api/v1/studies/{study['id']}/ask", json={"count": 64}).json()["trials"]
        )
    acknowledged: dict[int, float] = {}
    stop = threading.Event()

    def stream(offset: int) -> None:
        with httpx.Client(
            base_url=server.url, timeout=5, headers=SDK_HEADERS, verify=False
        ) as http:
            for trial in trials[offset::4]:
                if stop.is_set():
                    return
                value = trial["id"] + 0.25
                try:
                    told = http.post(f"/api/v1/trials/{trial['id']}/tell", json={"value": value})
                except httpx.TransportError:
                    return  # the server died under this request: not acknowledged
                if told.status_code == 200:
                    acknowledged[trial["id"]] = value

    threads = [threading.Thread(target=stream, args=(i,)) for i in range(4)]
    for thread in threads:
        thread.start()
    while len(acknowledged) < 40:
        time.sleep(0.005)
    server.kill()
    stop.set()
    for thread in threads:
        thread.join()
    assert 40 <= len(acknowledged) < len(trials)

    server.start()
    with httpx.Client(base_url=server.url, timeout=10, headers=SDK_HEADERS, verify=False) as http:
        stored = http.get(f"/api/v1/studies/{study['id']}/trials").json()
        info = http.get(f"/api/v1/studies/{study['id']}").json()
    values = {t["id"]: t["value"] for t in stored if t["state"] == "complete"}
    assert {tid: values.get(tid) for tid in acknowledged} == acknowledged
    assert info["n_complete"] == len(values)  # counters agree with the rows after the crash


def test_interrupted_upload_is_never_served(shared_server: ServerProcess) -> None:
    with httpx.Client(
        base_url=shared_server.url, timeout=10, headers=SDK_HEADERS, verify=False
    ) as http:
        trial = one_trial(http)
    path = f"/api/v1/trials/{trial['id']}/artifacts/robot.png"
    # Declare 100 kB, send 10 kB, hang up: the upload never completes.
    with socket.create_connection(("127.0.0.1", shared_server.port)) as sock:
        sock.sendall(
            f"PUT {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: image/png\r\n"
            "X-Activedesign-Client: test\r\n"
            f"Content-Length: 100000\r\n\r\n".encode()
            + b"\x89PNG" * 2500
        )
        time.sleep(0.3)
    with httpx.Client(
        base_url=shared_server.url, timeout=10, headers=SDK_HEADERS, verify=False
    ) as http:
        assert http.get(path).status_code == 404
        assert http.get(f"/api/v1/trials/{trial['id']}/artifacts").json() == []
        image = b"\x89PNG\r\n\x1a\n" * 5
        complete = http.put(path, content=image, headers={"Content-Type": "image/png"})
        assert complete.status_code == 201 and complete.json()["size"] == 40
        served = http.get(path)
        assert served.status_code == 200 and served.content == image
        assert served.headers["content-type"] == "image/png"
    leftovers = list(shared_server.artifact_dir.rglob(".upload-*"))
    assert leftovers == []


def test_truncated_artifact_file_is_not_served(shared_server: ServerProcess) -> None:
    with httpx.Client(
        base_url=shared_server.url, timeout=10, headers=SDK_HEADERS, verify=False
    ) as http:
        trial = one_trial(http)
        path = f"/api/v1/trials/{trial['id']}/artifacts/curve.json"
        http.put(path, content=b'{"curve": [1, 2, 3]}')
        folder = shared_server.artifact_dir / str(trial["study_id"])  # this study's
        (stored,) = list(folder.rglob("curve.json.*"))
        stored.write_bytes(b'{"curve": [1,')  # damaged on disk behind the server's back
        response = http.get(path)
        assert response.status_code == 404 and "incomplete" in response.json()["detail"]


@pytest.mark.parametrize("name", ["..", "a/b", "..%2F..%2Fetc", ".hidden", "x" * 200])
def test_artifact_names_cannot_escape(shared_server: ServerProcess, name: str) -> None:
    """On the module's server: these cases put an artifact holding ``x`` there (the
    module's other tests upload other bytes), and all are refused, so no file under its
    folder holds their content."""
    with httpx.Client(
        base_url=shared_server.url, timeout=10, headers=SDK_HEADERS, verify=False
    ) as http:
        trial = one_trial(http)
        response = http.put(f"/api/v1/trials/{trial['id']}/artifacts/{name}", content=b"x")
        assert response.status_code in (404, 405, 422)
    escaped = [
        p for p in shared_server.workdir.rglob("*") if p.is_file() and p.read_bytes() == b"x"
    ]
    assert escaped == []


def test_oversized_artifact_is_413_and_not_stored(
    server_factory: Callable[..., ServerProcess],
) -> None:
    server = server_factory(AD_MAX_ARTIFACT_BYTES="1000")
    with httpx.Client(base_url=server.url, timeout=10, headers=SDK_HEADERS, verify=False) as http:
        trial = one_trial(http)
        path = f"/api/v1/trials/{trial['id']}/artifacts/big.bin"
        assert http.put(path, content=b"x" * 5000).status_code == 413

        def chunks() -> object:
            for _ in range(10):
                yield b"y" * 500  # no Content-Length: counted while streaming

        assert http.put(path, content=chunks()).status_code == 413
        assert http.get(path).status_code == 404
