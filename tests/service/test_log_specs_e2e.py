"""A design study with log-scaled specs (``{low, high, log: true}``) against a real server,
on SQLite and PostgreSQL: its proposals spread such a spec log-uniformly, the URDF carries
the decoded value, an enqueued design comes back as it was, and a bad log spec is a 422
naming it."""

from __future__ import annotations

import math
import statistics
import xml.etree.ElementTree as ET
from typing import Any

import httpx
import pytest

from adclient.testing.servers import ServerProcess

pytestmark = [pytest.mark.e2e, pytest.mark.xdist_group("log-specs")]

MASS = (0.01, 100.0)
"""A log-scaled spec over four decades: geometric mean 1, arithmetic mean 50.005."""
LENGTH = (0.2, 0.6)
"""A linear spec beside it, for contrast."""

SPACE: dict[str, Any] = {
    "type": "design",
    "parts": {
        "link": {
            "length": {"low": LENGTH[0], "high": LENGTH[1]},
            "mass": {"low": MASS[0], "high": MASS[1], "log": True},
        }
    },
    "joint": {"axis_theta": 1.0, "axis_phi": 0.0},
    "instances": [{"name": "a", "part": "link"}, {"name": "b", "part": "link"}],
    "structures": [[["a", "b"]]],
}


def create(http: httpx.Client, proposer: str) -> int:
    body = {"name": f"log specs, {proposer}", "space": SPACE, "proposer": {"name": proposer}}
    created = http.post("/api/v1/studies", json=body)
    assert created.status_code == 201, created.text
    # the stored space says which spec is log-scaled, and only that one
    assert created.json()["space"]["parts"]["link"]["mass"]["log"] is True
    assert "log" not in created.json()["space"]["parts"]["link"]["length"]
    return int(created.json()["id"])


def ask(http: httpx.Client, sid: int, count: int) -> list[dict[str, Any]]:
    asked = http.post(f"/api/v1/studies/{sid}/ask", json={"count": count})
    assert asked.status_code == 200, asked.text
    return list(asked.json()["trials"])


@pytest.mark.parametrize("proposer", ["sobol", "random"])
def test_proposals_spread_a_log_spec_log_uniformly(
    shared_server: ServerProcess, proposer: str
) -> None:
    with httpx.Client(base_url=shared_server.url, timeout=60, verify=False) as http:
        sid = create(http, proposer)
        trials = ask(http, sid, 64) + ask(http, sid, 64)
    masses = [t["params"][f"{link}.mass"] for t in trials for link in "ab"]
    lengths = [t["params"][f"{link}.length"] for t in trials for link in "ab"]
    assert all(MASS[0] <= m <= MASS[1] for m in masses)
    geometric, arithmetic = math.sqrt(MASS[0] * MASS[1]), sum(MASS) / 2
    median = statistics.median(masses)
    # Log-uniform: the median near the geometric mean (1), far below the arithmetic
    # mean (50); a uniform draw would put it near 50.
    assert geometric / 3 < median < geometric * 3 < arithmetic / 10
    # each decade holds about a quarter of the 256 values (64 if log-uniform; a
    # uniform draw would put 0.1% of them in the lowest two decades)
    decades = [sum(10.0**k <= m < 10.0 ** (k + 1) for m in masses) for k in (-2, -1, 0, 1)]
    decades[-1] += masses.count(MASS[1])
    assert all(40 <= count <= 88 for count in decades), decades
    # the linear spec beside it stays uniform: its median near the middle of its range
    assert statistics.median(lengths) == pytest.approx(sum(LENGTH) / 2, abs=0.05)
    # a trial's vector is the log coordinate, in [0, 1]
    for trial in trials[:8]:
        mass = trial["params"]["a.mass"]
        expected = math.log(mass / MASS[0]) / math.log(MASS[1] / MASS[0])
        assert trial["vector"][1] == pytest.approx(expected, abs=1e-12)


def test_an_enqueued_log_design_round_trips(shared_server: ServerProcess) -> None:
    with httpx.Client(base_url=shared_server.url, timeout=60, verify=False) as http:
        sid = create(http, "random")
        asked = ask(http, sid, 4)
        url = f"/api/v1/studies/{sid}/trials"
        again = http.post(url, json=[{"params": t["params"]} for t in asked])
        assert again.status_code == 201, again.text
        for original, enqueued in zip(asked, again.json(), strict=True):
            assert enqueued["state"] == "queued"
            assert enqueued["params"] == original["params"]  # every value, bit for bit
            assert enqueued["vector"] == pytest.approx(original["vector"], abs=1e-12)
        # a design of the user's own: mass 1 sits in the middle of the log coordinate
        own = dict(asked[0]["params"], **{"a.mass": 1.0, "b.mass": 0.1})
        handed = http.post(url, json={"params": own})
        assert handed.status_code == 201, handed.text
        # (a value of one's own comes back to the slot's resolution, a few ulps: not
        # every float is exp of a float; one the server decoded comes back exactly)
        assert handed.json()["params"]["a.mass"] == pytest.approx(1.0, rel=1e-15)
        assert handed.json()["params"]["b.mass"] == pytest.approx(0.1, rel=1e-15)
        assert handed.json()["vector"][1] == pytest.approx(0.5, abs=1e-12)
        assert handed.json()["vector"][3] == pytest.approx(0.25, abs=1e-12)
        # the URDF is written from the decoded (physical) values
        urdf = http.get(f"/api/v1/trials/{handed.json()['id']}/urdf")
        assert urdf.status_code == 200, urdf.text
        masses = {
            link.get("name"): float(link.find("inertial/mass").get("value"))  # type: ignore[union-attr]
            for link in ET.fromstring(urdf.content).findall("link")
        }
        assert masses == {"a": pytest.approx(1.0), "b": pytest.approx(0.1)}
        # the queued design is what the next ask hands out
        (first,) = ask(http, sid, 1)
        assert first["id"] == again.json()[0]["id"]
        refused = http.post(url, json={"params": dict(own, **{"a.mass": 0.001})})
        assert refused.status_code == 422
        assert "'a.mass' = 0.001 lies outside [0.01, 100.0]" in refused.json()["detail"]


def test_a_log_spec_needs_low_above_zero(shared_server: ServerProcess) -> None:
    space = {**SPACE, "joint": {"effort": {"low": 0.0, "high": 10.0, "log": True}}}
    with httpx.Client(base_url=shared_server.url, timeout=60, verify=False) as http:
        before = http.get("/api/v1/studies").json()
        refused = http.post("/api/v1/studies", json={"name": "bad log", "space": space})
        assert refused.status_code == 422
        detail = refused.json()["detail"]
        assert "space.design.joint.effort" in detail
        assert "log: a log scale needs low > 0, got 0.0" in detail
        assert http.get("/api/v1/studies").json() == before  # nothing stored
