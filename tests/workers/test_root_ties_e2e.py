"""Ties to the root end to end (issue 36): a space whose joints choose motors and
whose instance is tied to the root (``c same_as a`` in the chain a-b-c, ``b same_as a``
mirrored, or chained) was created, every ask answered 500 (``encode: spec
'a.joint.choice.0' is missing``), and as a managed study it stopped the workers. On a
real adserver each asks, its asked design enqueues back unchanged, and a real adworker
completes its trials: the tied joint has a motor of the catalogue, its URDF that
motor's effort. tests/service/test_space_properties.py checks every feature's spaces."""

from __future__ import annotations

import xml.etree.ElementTree as ElementTree
from typing import Any

import httpx
import pytest

from adclient import Client
from adclient.testing.workers import completed_trials

pytestmark = pytest.mark.e2e

MOTORS = {
    "small": {"effort": 2.0, "velocity": 6.0, "cost": 10.0},
    "mid": {"effort": 5.0, "velocity": 4.0, "cost": 20.0},
    "large": {"effort": 9.0, "velocity": 3.0, "cost": 40.0},
}
TIES: dict[str, tuple[str, list[dict[str, Any]]]] = {
    "the last link tied to the root": ("c", [{"name": "c", "same_as": "a"}]),
    "a child mirroring the root": ("b", [{"name": "b", "same_as": "a", "mirror": "y"}]),
    "a chain to the root": (
        "c",
        [{"name": "b", "same_as": "a", "mirror": "x"}, {"name": "c", "same_as": "b"}],
    ),
}


def _study(name: str, tied: list[dict[str, Any]]) -> dict[str, Any]:
    instances = {link: {"name": link, "part": "link"} for link in "abc"}
    instances.update({instance["name"]: instance for instance in tied})
    return {
        "name": name,
        "space": {
            "type": "design",
            "catalogues": {"motors": MOTORS},
            "parts": {"link": {"length": {"low": 0.1, "high": 0.3}, "radius": 0.02, "mass": 0.2}},
            "joint": {"choose": "motors"},
            "instances": list(instances.values()),
            "structures": [[["a", "b"], ["b", "c"]]],
        },
        "proposer": {"name": "random", "seed": 1},
        "task": {"name": "lift-highest", "learner": "fast", "train_steps": 64, "eval_episodes": 1},
        "max_trials": 3,
    }


def test_spaces_tied_to_the_root_ask_enqueue_and_run_on_a_real_worker(server, workers):
    with Client(server.url) as client:
        studies = {}
        for name, (tied_child, tied) in TIES.items():
            study = client.create_study(_study(name, tied))
            asked = study.ask()
            assert asked.params[f"{tied_child}.joint.choice"] in MOTORS
            enqueued = study.enqueue_trial(dict(asked.params))
            assert enqueued.params == asked.params
            study.tell(asked, state="failed")  # the worker runs the enqueued one and one more
            studies[tied_child, name] = study
        workers(server, "roots")
        for (tied_child, _), study in studies.items():
            for trial in completed_trials(study, 2):
                motor = MOTORS[trial.params[f"{tied_child}.joint.choice"]]
                assert trial.params[f"{tied_child}.joint.effort"] == motor["effort"]
                urdf = httpx.get(f"{server.url}/api/v1/trials/{trial.id}/urdf").text
                assert _efforts(urdf)[tied_child] == motor["effort"]


def _efforts(urdf: str) -> dict[str, float]:
    """Each joint's effort limit in a URDF, by its child link."""
    efforts = {}
    for joint in ElementTree.fromstring(urdf).iter("joint"):
        child, limit = joint.find("child"), joint.find("limit")
        assert child is not None and limit is not None
        efforts[child.get("link", "")] = float(limit.get("effort", "nan"))
    return efforts
