"""Catalogues end to end (issue 28): a real adserver and a real adworker run the
catalogue-arm example; each trial's joints are servos of the catalogue with their specs,
in its params and its URDF, its metrics sum the chosen servos' entries, and an enqueued
design whose spec is not its servo's is a 422 that stores nothing."""

from __future__ import annotations

import xml.etree.ElementTree as ElementTree

import httpx
import pytest

from adclient import Client
from adclient.errors import Invalid
from adclient.testing.workers import completed_trials
from tests.workers.robots import example_study

pytestmark = pytest.mark.e2e


def test_the_catalogue_arm_runs_with_servos_and_reports_their_cost(server, workers):
    body = example_study("catalogue-arm").model_dump(mode="json")
    servos = body["space"]["catalogues"]["servos"]
    body["max_trials"] = 3
    body["task"].update(train_steps=64, eval_episodes=1)
    with Client(server.url) as client:
        study = client.create_study(body)
        first = study.ask()
        params = dict(first.params)
        study.tell(first, state="failed")  # the worker runs the rest

        before = len(study.trials)
        with pytest.raises(Invalid, match=r"'c.joint.effort' = 99.0 .* catalogue 'servos'"):
            study.enqueue_trial({**params, "c.joint.effort": 99.0})
        with pytest.raises(Invalid, match=r"'xm999' is no component of catalogue 'servos'"):
            study.enqueue_trial({**params, "c.joint.choice": "xm999"})
        assert len(study.trials) == before
        chosen = {**params, "b.joint.choice": "pm42", "c.joint.choice": "xl330"}
        for joint in "bcd":
            chosen.pop(f"{joint}.joint.effort")
            chosen.pop(f"{joint}.joint.velocity")
        enqueued = study.enqueue_trial(chosen)
        assert enqueued.params["b.joint.effort"] == servos["pm42"]["effort"]

        workers(server, "servo")
        for trial in completed_trials(study, 2):
            names = [trial.params[f"{joint}.joint.choice"] for joint in "bcd"]
            cost = sum(servos[name]["cost"] for name in names)
            assert trial.metrics["servos.cost"] == pytest.approx(cost)
            urdf = httpx.get(f"{server.url}/api/v1/trials/{trial.id}/urdf").text
            limits = {
                joint.find("child").get("link"): float(joint.find("limit").get("effort"))
                for joint in ElementTree.fromstring(urdf).iter("joint")
            }
            assert limits == {j: servos[n]["effort"] for j, n in zip("bcd", names, strict=True)}
