"""A mirrored limb moves as the mirror image of its source in PyBullet: the same joint
angle puts its tip where the source's tip is, reflected (issue 28, ``mirror``)."""

from __future__ import annotations

import numpy as np
import pybullet
import pytest

from adclient.decode import decode, identity_representation
from adclient.design import DesignSpace
from adclient.urdf import design_to_urdf

REFLECT = {"x": np.array([-1.0, 1.0, 1.0]), "y": np.array([1.0, -1.0, 1.0])}


def _space(mirror: str) -> DesignSpace:
    return DesignSpace.model_validate(
        {
            "type": "design",
            "parts": {
                "body": {"length": 0.3, "radius": 0.05, "mass": 2.0},
                "thigh": {"length": {"low": 0.15, "high": 0.3}, "radius": 0.02, "mass": 0.3},
                "shin": {"length": {"low": 0.15, "high": 0.3}, "radius": 0.02, "mass": 0.2},
            },
            "instances": [
                {"name": "torso", "part": "body"},
                {"name": "left", "part": "thigh"},
                {"name": "left_shin", "part": "shin"},
                {"name": "right", "same_as": "left", "mirror": mirror},
                {"name": "right_shin", "same_as": "left_shin", "mirror": mirror},
            ],
            "structures": [
                [
                    ["torso", "left"],
                    ["left", "left_shin"],
                    ["torso", "right"],
                    ["right", "right_shin"],
                ]
            ],
        }
    )


def _tips(urdf: str, tmp_path, angles: tuple[float, float]) -> dict[str, np.ndarray]:
    """Every link's far end in the base's frame, both legs' joints at ``angles``."""
    path = tmp_path / "robot.urdf"
    path.write_text(urdf, encoding="utf-8")
    client = pybullet.connect(pybullet.DIRECT)
    try:
        body = pybullet.loadURDF(str(path), useFixedBase=True, physicsClientId=client)
        names = {}
        for index in range(pybullet.getNumJoints(body, physicsClientId=client)):
            info = pybullet.getJointInfo(body, index, physicsClientId=client)
            names[info[12].decode()] = index
        for leg in ("left", "right"):
            pybullet.resetJointState(body, names[leg], angles[0], physicsClientId=client)
            pybullet.resetJointState(body, names[f"{leg}_shin"], angles[1], physicsClientId=client)
        tips = {}
        for name, index in names.items():
            state = pybullet.getLinkState(
                body, index, computeForwardKinematics=True, physicsClientId=client
            )
            origin, orientation = np.array(state[4]), state[5]
            along = np.array(pybullet.getMatrixFromQuaternion(orientation)).reshape(3, 3)[:, 2]
            tips[name] = origin + along * 0.2
        return tips
    finally:
        pybullet.disconnect(client)


@pytest.mark.parametrize("mirror", ["x", "y"])
@pytest.mark.parametrize("seed", range(4))
def test_a_mirrored_leg_moves_as_the_mirror_image_of_its_source(mirror, seed, tmp_path) -> None:
    space = _space(mirror)
    representation = identity_representation(space)
    rng = np.random.default_rng(seed)
    design = decode(space, representation, rng.random(len(representation.bounds[0])).tolist())
    urdf = design_to_urdf(design)
    for angles in [(0.0, 0.0), tuple(rng.uniform(-1.5, 1.5, size=2))]:
        tips = _tips(urdf, tmp_path, angles)
        for part in ("left", "left_shin"):
            mirrored = tips[part.replace("left", "right")]
            assert mirrored == pytest.approx(tips[part] * REFLECT[mirror], abs=1e-9), (part, angles)
    moved = _tips(urdf, tmp_path, (0.7, -0.4))["left_shin"]
    assert not np.allclose(moved, _tips(urdf, tmp_path, (0.0, 0.0))["left_shin"])
