"""Design studies over HTTP from each example file: trials carry real designs and URDFs."""

from __future__ import annotations

import itertools
import xml.etree.ElementTree as ET
from pathlib import Path

import httpx
import pybullet
import pytest
import yaml

from adclient.decode import decode
from adclient.design import DesignSpace
from adclient.designs import Representation
from adclient.testing.servers import ServerProcess

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
_COUNTER = itertools.count()


@pytest.mark.e2e
@pytest.mark.slow
def test_example_studies_give_real_designs(live_server: ServerProcess, tmp_path: Path) -> None:
    cid = pybullet.connect(pybullet.DIRECT)
    try:
        with httpx.Client(base_url=live_server.url, timeout=60) as http:
            for name in ("stand-up", "diagonal-gesture", "multi-structure"):
                body = yaml.safe_load((EXAMPLES / f"{name}.yaml").read_text())
                created = http.post("/api/v1/studies", json=body)
                assert created.status_code == 201, created.text
                study = created.json()
                space = DesignSpace.model_validate(study["space"])
                asked = http.post(f"/api/v1/studies/{study['id']}/ask", json={"count": 3})
                assert asked.status_code == 200, asked.text
                for trial in asked.json()["trials"]:
                    params = trial["params"]
                    structure = space.tree_structures()[params["structure_index"]]
                    assert sorted(params["structure"].split(",")) == sorted(
                        f"{parent}-{child}" for parent, child in structure
                    )
                    for child in (child for _, child in structure):
                        assert f"{child}.joint.axis_theta" in params
                    reply = http.get(f"/api/v1/trials/{trial['id']}/urdf")
                    assert reply.status_code == 200, reply.text
                    robot = ET.fromstring(reply.content)
                    links = {link.get("name") for link in robot.findall("link")}
                    assert links == {n for edge in structure for n in edge}
                    assert len(robot.findall("joint")) == len(structure)
                    path = tmp_path / f"trial-{next(_COUNTER)}.urdf"
                    path.write_bytes(reply.content)
                    body_id = pybullet.loadURDF(str(path), physicsClientId=cid)
                    assert pybullet.getNumJoints(body_id, physicsClientId=cid) == len(structure)
                    for index in range(len(structure)):
                        info = pybullet.getJointInfo(body_id, index, physicsClientId=cid)
                        child = info[12].decode()
                        assert info[13] == pytest.approx(params[f"{child}.joint.axis"], abs=1e-9)
                    pybullet.removeBody(body_id, physicsClientId=cid)
    finally:
        pybullet.disconnect(physicsClientId=cid)


def test_representations_survive_json_like_a_job() -> None:
    """What a worker receives (space and representation as JSON) decodes alike."""
    from adservice.representation import build_representation

    for name in ("stand-up", "multi-structure"):
        space = DesignSpace.model_validate(
            yaml.safe_load((EXAMPLES / f"{name}.yaml").read_text())["space"]
        )
        representation = build_representation(space)
        shipped_space = DesignSpace.model_validate_json(space.model_dump_json())
        shipped = Representation.model_validate_json(representation.model_dump_json())
        low, high = representation.bounds
        vector = [(lo + hi) / 2 for lo, hi in zip(low, high, strict=True)]
        assert decode(shipped_space, shipped, vector) == decode(space, representation, vector)
