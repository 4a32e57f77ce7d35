"""Tied limbs end to end (issue 28): a real adserver and a real adworker run the
quadruped example; every trial's params and URDF show the tied legs equal and the
mirrored ones reflected, an enqueued design that breaks a tie is a 422 that stores
nothing, and one that leaves the tied specs out is taken."""

from __future__ import annotations

import xml.etree.ElementTree as ElementTree

import httpx
import pytest

from adclient import Client
from adclient.errors import Invalid
from adclient.testing.workers import completed_trials
from tests.workers.robots import example_study

pytestmark = pytest.mark.e2e

LEGS = ("front_right", "back_left", "back_right")


def _axes(urdf: str) -> dict[str, tuple[float, ...]]:
    root = ElementTree.fromstring(urdf)
    return {
        joint.find("child").get("link"): tuple(map(float, joint.find("axis").get("xyz").split()))
        for joint in root.iter("joint")
    }


def test_the_quadruped_runs_with_tied_legs_and_a_broken_tie_is_refused(server, workers):
    body = example_study("quadruped").model_dump(mode="json")
    body["max_trials"] = 3
    body["task"].update(train_steps=64, eval_episodes=1)
    with Client(server.url) as client:
        study = client.create_study(body)
        assert len(study.info.space.instances) == 9
        first = study.ask()
        params = dict(first.params)
        study.tell(first, state="failed")  # the worker runs the rest

        broken = {**params, "back_left.length": params["front_left.length"] * 0.5}
        before = len(study.trials)
        with pytest.raises(Invalid, match=r"back_left\.length.*tied to 'front_left'"):
            study.enqueue_trial(broken)
        assert len(study.trials) == before

        own = {key: value for key, value in params.items() if key.split(".")[0] not in LEGS}
        own["front_left.length"] = 0.3
        enqueued = study.enqueue_trial(own)
        assert enqueued.params["back_right.length"] == 0.3

        workers(server, "legs")
        for trial in completed_trials(study, 2):
            for leg in LEGS:
                for part in ("", "_shin"):
                    assert (
                        trial.params[f"{leg}{part}.length"]
                        == trial.params[f"front_left{part}.length"]
                    )
            urdf = httpx.get(f"{server.url}/api/v1/trials/{trial.id}/urdf").text
            axes = _axes(urdf)
            ax, ay, az = axes["front_left"]
            assert axes["back_left"] == pytest.approx((ax, ay, az))
            for mirrored in ("front_right", "back_right"):
                assert axes[mirrored] == pytest.approx((-ax, ay, -az), abs=1e-8)
