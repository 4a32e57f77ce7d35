"""The proposer's torch device is a server setting (``AD_PROPOSER_DEVICE``): qEI fits on
the CPU by default, and a server asked for cuda where there is none does not start."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import httpx
import pytest
import torch

from adclient.testing.servers import ADSERVER, ServerProcess, free_port, refused_at_start

pytestmark = pytest.mark.e2e

BOX = {"type": "box", "params": [{"name": f"x{i}", "low": 0.0, "high": 1.0} for i in range(2)]}


def test_qei_fits_on_the_cpu_by_default(server_factory: Callable[..., ServerProcess]) -> None:
    server = server_factory()
    with httpx.Client(base_url=server.url, timeout=300) as http:
        body = {"name": "q", "space": BOX, "proposer": {"name": "qei", "n_initial": 2}}
        study = http.post("/api/v1/studies", json=body).json()["id"]
        for value, trial in enumerate(
            http.post(f"/api/v1/studies/{study}/ask", json={"count": 3}).json()["trials"]
        ):
            assert http.post(f"/api/v1/trials/{trial['id']}/tell", json={"value": value}).is_success
        (fitted,) = http.post(f"/api/v1/studies/{study}/ask", json={"count": 1}).json()["trials"]
    assert not fitted["info"]["method"].startswith("sobol"), fitted["info"]
    assert fitted["info"]["device"] == "cpu"


@pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has a CUDA GPU")
def test_a_server_asked_for_cuda_without_a_gpu_exits_saying_why(tmp_path: Path) -> None:
    database = f"sqlite:///{tmp_path / 'studies.db'}"
    command = [str(ADSERVER), "--port", str(free_port()), "--database-url", database]
    said = refused_at_start(command, 2, AD_PROPOSER_DEVICE="cuda")
    assert said.startswith("adserver: AD_PROPOSER_DEVICE=cuda cannot be used: ")
    assert "AD_PROPOSER_DEVICE=cpu" in said
    assert not (tmp_path / "studies.db").exists()  # refused before touching the database


@pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has a CUDA GPU")
@pytest.mark.parametrize("objectives", [1, 2])
@pytest.mark.parametrize("shared_server", ["sqlite"], indirect=True)  # refused before storing
def test_a_study_asking_for_cuda_on_a_server_without_it_is_refused_at_creation(
    shared_server: ServerProcess, objectives: int
) -> None:
    """Accepted, every ask of it would fall back to Sobol points ("model failed"); one
    objective (qLogEI) or several (qLogNEHVI) alike."""
    body: dict[str, Any] = {
        "name": f"cuda-{objectives}",
        "space": BOX,
        "proposer": {"name": "qei", "options": {"device": "cuda"}},
    }
    if objectives == 2:
        body["objectives"] = [
            {"metric": "score", "direction": "maximize"},
            {"metric": "mass", "direction": "minimize"},
        ]
    with httpx.Client(base_url=shared_server.url, timeout=60) as http:
        refused = http.post("/api/v1/studies", json=body)
        assert refused.status_code == 422, refused.text
        detail = refused.json()["detail"]
        assert "proposer.options.device: cuda cannot be used on this server" in detail, detail
        assert "set it to cpu" in detail
        names = [s["name"] for s in http.get("/api/v1/studies").json()]
        assert f"cuda-{objectives}" not in names  # nothing stored
        body["proposer"]["options"]["device"] = "cpu"
        assert http.post("/api/v1/studies", json=body).status_code == 201
