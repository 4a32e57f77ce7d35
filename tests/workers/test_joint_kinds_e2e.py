"""Joint kinds, offsets and capsules end to end (issue 28): a real adserver and a real
adworker run a study whose robot has a continuous wheel, a prismatic lift, a fixed mast
turned on its parent and capsule links; each trial's params show the kinds, its URDF
has them, and its mass metric counts the capsules' balls."""

from __future__ import annotations

import math
import xml.etree.ElementTree as ElementTree

import httpx
import pytest

from adclient import Client
from adclient.specs import link_volume
from adclient.testing.workers import completed_trials
from tests.workers.robots import example_study

pytestmark = pytest.mark.e2e


def small_study() -> dict:
    """examples/joint-kinds.yaml, two trials of a small budget."""
    body = example_study("joint-kinds").model_dump(mode="json")
    body["max_trials"] = 2
    body["task"].update(train_steps=64, eval_episodes=1)
    return body


def test_a_study_of_joint_kinds_runs_on_a_real_worker(server, workers):
    with Client(server.url) as client:
        study = client.create_study(small_study())
        workers(server, "kinds")
        for trial in completed_trials(study, 2):
            params = trial.params
            assert [params.get(f"{name}.joint.kind") for name in ("wheel", "lift", "mast")] == [
                "continuous",
                "prismatic",
                "fixed",
            ]
            assert params["mast.joint.offset_roll"] == 0.5
            urdf = ElementTree.fromstring(
                httpx.get(f"{server.url}/api/v1/trials/{trial.id}/urdf").text
            )
            kinds = {j.find("child").get("link"): j.get("type") for j in urdf.iter("joint")}  # type: ignore[union-attr]
            assert kinds == {"wheel": "continuous", "lift": "prismatic", "mast": "fixed"}
            rods = sum(
                800.0 * link_volume("capsule", params[f"{name}.length"], 0.03)
                for name in ("wheel", "lift", "mast")
            )
            assert trial.metrics["mass"] == pytest.approx(2.0 + rods, rel=1e-9)
            assert math.isfinite(trial.value)
