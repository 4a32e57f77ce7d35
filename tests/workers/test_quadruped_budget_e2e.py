"""The quadruped-budget example end to end (issue 28): ties, catalogue servos, a
leg-length budget, a servo-mass budget, capsule shins and splayed (offset) thighs,
together, on a real adserver and a real adworker."""

from __future__ import annotations

import pytest

from adclient import Client
from adclient.testing.workers import completed_trials
from tests.workers.robots import example_study

pytestmark = pytest.mark.e2e

LEGS = ("front_left", "front_right", "back_left", "back_right")


def test_the_quadruped_budget_example_runs(server, workers):
    body = example_study("quadruped-budget").model_dump(mode="json")
    servos = body["space"]["catalogues"]["servos"]
    body["max_trials"] = 3
    body["task"].update(train_steps=64, eval_episodes=1)
    with Client(server.url) as client:
        study = client.create_study(body)
        workers(server, "budget")
        for trial in completed_trials(study, 3):
            params = trial.params
            assert params["front_left.length"] + params["front_left_shin.length"] <= 0.5 + 1e-9
            chosen = [params[f"{leg}{part}.joint.choice"] for leg in LEGS for part in ("", "_shin")]
            assert chosen[0::2] == [chosen[0]] * 4 and chosen[1::2] == [chosen[1]] * 4  # tied
            masses = sum(servos[name]["mass"] for name in chosen)
            assert trial.metrics["servos.mass"] == pytest.approx(masses)
            assert trial.feasible == (masses <= 1.0)
            yaws = [params[f"{leg}.joint.offset_yaw"] for leg in LEGS]
            assert yaws == [0.2, -0.2, 0.2, -0.2]  # the right legs splay the mirror way
