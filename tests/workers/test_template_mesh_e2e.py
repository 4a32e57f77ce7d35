"""Issue 58: a visual mesh at a local path, in a URDF an older server stored for a
template trial (before, a link with collisions had its visuals unread, and the path
went on to PyBullet), fails the trial on a real ``adworker`` before anything reads the
URDF, naming why; the worker stays up."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import httpx
import pytest
import yaml

from adclient.testing.servers import ServerProcess
from adclient.testing.workers import PATIENCE
from tests.harmful_urdfs import HOSTNAME_MESH, store_urdf

pytestmark = [pytest.mark.slow, pytest.mark.e2e]

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def test_a_stored_visual_mesh_fails_the_trial_on_the_worker(server: ServerProcess, workers) -> None:
    body: dict[str, Any] = yaml.safe_load((EXAMPLES / "template-arm.yaml").read_text())
    body["space"]["template"] = (EXAMPLES / body["space"]["template"]).read_text()
    body["task"].update(train_steps=64, eval_episodes=1)
    body.update(name="stored-mesh", proposer={"name": "random", "seed": 6}, max_trials=1)
    with httpx.Client(base_url=server.url, timeout=60, verify=False) as http:
        created = http.post("/api/v1/studies", json=body)
        assert created.status_code == 201, created.text
        params = {"upper_length": 0.2, "fore_length": 0.3, "hand_radius": 0.04}
        added = http.post(f"/api/v1/studies/{created.json()['id']}/trials", json={"params": params})
        assert added.status_code == 201, added.text
        trial_id = added.json()["id"]
        urdf = http.get(f"/api/v1/trials/{trial_id}/urdf").text
        assert "<collision>" in urdf
        mesh = f"</collision><visual><geometry>{HOSTNAME_MESH}</geometry></visual>"
        store_urdf(server.database_url, trial_id, urdf.replace("</collision>", mesh, 1))

        worker = workers(server, "mesh")
        deadline = time.monotonic() + PATIENCE
        while (trial := http.get(f"/api/v1/trials/{trial_id}").json())["state"] == "queued" or (
            trial["state"] == "running"
        ):
            assert time.monotonic() < deadline, worker.log()
            time.sleep(0.2)
    assert trial["state"] == "failed", (trial, worker.log())
    assert "its geometry is <mesh> (in a <visual>)" in trial["message"], trial["message"]
    assert worker.process.poll() is None, worker.log()  # the worker goes on
