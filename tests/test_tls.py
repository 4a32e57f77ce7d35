"""HTTPS end to end: a real ``adserver --ssl-certfile/--ssl-keyfile`` with a self-signed
certificate made here, the SDK and a real ``adworker`` trusting it through a CA bundle."""

from __future__ import annotations

import shutil
import subprocess
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from adclient import Client
from adclient.errors import Unavailable
from adclient.testing.servers import ServerProcess
from adclient.testing.workers import PATIENCE, WorkerProcess
from tests.workers.robots import stand_up_study

pytestmark = pytest.mark.e2e


@dataclass
class HttpsServer(ServerProcess):
    @property
    def url(self) -> str:
        return f"https://127.0.0.1:{self.port}"


@pytest.fixture(scope="module")
def certificate(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A self-signed certificate for 127.0.0.1 and its key (PEM files)."""
    if shutil.which("openssl") is None:
        pytest.skip("openssl is not installed")
    folder = tmp_path_factory.mktemp("tls")
    cert, key = folder / "cert.pem", folder / "key.pem"
    command = ["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "2"]
    command += ["-keyout", str(key), "-out", str(cert), "-subj", "/CN=127.0.0.1"]
    command += ["-addext", "subjectAltName=IP:127.0.0.1,DNS:localhost"]
    subprocess.run(command, check=True, capture_output=True)
    return cert, key


@pytest.fixture
def server(
    tmp_path: Path, certificate: tuple[Path, Path], monkeypatch: pytest.MonkeyPatch
) -> Iterator[HttpsServer]:
    cert, key = certificate
    https = HttpsServer(
        database_url=f"sqlite:///{tmp_path / 'studies.db'}",
        workdir=tmp_path,
        env={"AD_SSL_CERTFILE": str(cert), "AD_SSL_KEYFILE": str(key)},
    )
    with monkeypatch.context() as patch:
        patch.setenv("SSL_CERT_FILE", str(cert))  # for start()'s own readiness check only
        https.start()
    yield https
    https.stop()


def test_the_sdk_asks_and_tells_over_https(
    server: HttpsServer, certificate: tuple[Path, Path]
) -> None:
    cert, _ = certificate
    with Client(server.url, verify=str(cert)) as client:
        study = client.create_study(
            name="tls",
            direction="minimize",
            space={"type": "box", "params": [{"name": "x", "low": -1, "high": 1}]},
            proposer={"name": "random", "seed": 1},
        )
        trial = study.ask()
        study.tell(trial, value=trial.params["x"] ** 2)
        assert client.study_info(study.id).n_complete == 1
    with Client(server.url, retries=0) as unverified, pytest.raises(Unavailable):
        unverified.studies()  # the system CAs do not know this certificate


def test_a_worker_completes_a_trial_over_https(
    server: HttpsServer, certificate: tuple[Path, Path], tmp_path: Path
) -> None:
    cert, _ = certificate
    with Client(server.url, verify=str(cert)) as client:
        study = stand_up_study(client, max_trials=1, learner="fast", train_steps=256)
        args = ("--ca-bundle", str(cert), "--max-jobs", "1", "--no-render")
        worker = WorkerProcess(server, tmp_path, "tls-worker", *args)
        try:
            assert worker.wait() == 0, worker.log()
        finally:
            worker.stop()
        final = study.wait(poll=0.2, timeout=PATIENCE)
    assert final.n_complete == 1, worker.log()
