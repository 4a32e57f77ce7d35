"""How a catalogue choice is searched (issue 28), through a real server: qei's initial
design deals every component to every choosing joint, and every stored vector puts a
choice exactly at its component's coordinates, whatever the proposer."""

from __future__ import annotations

from pathlib import Path

import httpx
import pytest
import yaml

from adclient.catalogues import coordinate
from adclient.decode import spec_layout
from adclient.design import DesignSpace

pytestmark = pytest.mark.e2e

ROOT = Path(__file__).resolve().parents[2]
ARM = yaml.safe_load((ROOT / "examples" / "catalogue-arm.yaml").read_text(encoding="utf-8"))
SERVOS = ARM["space"]["catalogues"]["servos"]


@pytest.fixture(scope="module")
def http(module_http: httpx.Client) -> httpx.Client:
    return module_http


def _study(http: httpx.Client, proposer: str, seed: int) -> int:
    body = {k: v for k, v in ARM.items() if k != "task"}
    body.update(name=f"servos-{proposer}-{seed}", proposer={"name": proposer, "seed": seed})
    created = http.post("/api/v1/studies", json=body)
    assert created.status_code == 201, created.text
    return created.json()["id"]


@pytest.mark.parametrize("seed", [0, 7])
def test_qei_starts_by_trying_every_servo_at_every_joint(http: httpx.Client, seed: int) -> None:
    study_id = _study(http, "qei", seed)
    trials = http.post(f"/api/v1/studies/{study_id}/ask", json={"count": 8}).json()["trials"]
    for joint in "bcd":
        assert {trial["params"][f"{joint}.joint.choice"] for trial in trials} == set(SERVOS)


@pytest.mark.parametrize("proposer", ["random", "sobol", "tpe", "qei"])
def test_a_stored_vector_puts_each_choice_at_its_component(
    http: httpx.Client, proposer: str
) -> None:
    study_id = _study(http, proposer, 3)
    names = spec_layout(DesignSpace.model_validate(ARM["space"])).names
    places = [coordinate(SERVOS, name, "0") for name in SERVOS]
    low, high = min(places), max(places)
    for _ in range(12):
        (trial,) = http.post(f"/api/v1/studies/{study_id}/ask", json={}).json()["trials"]
        for joint in "bcd":
            place = coordinate(SERVOS, trial["params"][f"{joint}.joint.choice"], "0")
            column = names.index(f"{joint}.joint.choice.0")
            assert trial["vector"][column] == pytest.approx((place - low) / (high - low), abs=1e-12)
        lengths = sum(trial["params"][f"{j}.length"] for j in "bcd")
        http.post(f"/api/v1/trials/{trial['id']}/tell", json={"value": lengths})
