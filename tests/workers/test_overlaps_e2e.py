"""Designs that can exist (issue 60), through a real adserver and adworker: a space
whose every design has links inside each other is refused at creation with a 422 naming
them, unless the study allows it; a single such design fails its trial with the reason
before any simulation, while the space's other designs are evaluated."""

from __future__ import annotations

import copy
import math
from pathlib import Path
from typing import Any

import httpx
import pytest

from adclient import Client
from adclient.testing.servers import ServerProcess
from adclient.testing.workers import WorkerProcess
from tests.workers.robots import CHAIN, HALF_PI, STAR, make_job, tree_design, two_tree_body

pytestmark = pytest.mark.e2e

SIDE_LEGS = {
    "name": "side-legs",
    "space": {
        "type": "design",
        "parts": {
            "body": {"shape": "box", "length": 0.4, "radius": 0.05, "mass": 2.0},
            "leg": {"length": {"low": 0.1, "high": 0.3}, "radius": 0.02, "mass": 0.3},
        },
        "joint": {"position": 0.5},
        "instances": [
            {"name": "torso", "part": "body"},
            {"name": "left", "part": "leg"},
            {"name": "right", "same_as": "left", "mirror": "y"},
        ],
        "structures": [[["torso", "left"], ["torso", "right"]]],
    },
    "task": {"name": "walk-forward", "learner": "fast"},
    "max_trials": 2,
}
"""The issue's space: legs set on the torso's side (mid-way along it) without
``offset_roll``, so at rest both lie along its axis, inside its box."""


def with_space(body: dict[str, Any], **space: Any) -> dict[str, Any]:
    changed = copy.deepcopy(body)
    changed["space"].update(space)
    return changed


def test_a_space_whose_every_design_hides_its_legs_in_its_torso_is_refused(
    server: ServerProcess,
) -> None:
    with httpx.Client(base_url=server.url, timeout=60, verify=False) as http:
        refused = http.post("/api/v1/studies", json=SIDE_LEGS)
        assert refused.status_code == 422, refused.text
        detail = str(refused.json()["detail"])
        assert "every design's links interpenetrate at the rest pose" in detail
        for pair in ("torso and left", "torso and right", "left and right"):
            assert pair in detail, detail
        assert "allow_overlaps: true" in detail
        assert http.get("/api/v1/studies").json() == []  # nothing stored

        # legs turned out of the torso's sides (the right one mirrors the left's roll)
        turned = copy.deepcopy(SIDE_LEGS)
        turned["space"]["instances"][1]["joint_overrides"] = {"offset_roll": -math.pi / 2}
        created = http.post("/api/v1/studies", json=turned)
        assert created.status_code == 201, created.text
        assert created.json()["space"]["allow_overlaps"] is False  # stored as checked
        # or the study says it means it
        allowed = http.post("/api/v1/studies", json=with_space(SIDE_LEGS, allow_overlaps=True))
        assert allowed.status_code == 201, allowed.text
        assert allowed.json()["space"]["allow_overlaps"] is True
        # a field of its own, not any key: an unknown one is still refused
        typo = http.post("/api/v1/studies", json=with_space(SIDE_LEGS, allow_overlap=True))
        assert typo.status_code == 422


def test_a_design_whose_limbs_lie_through_each_other_fails_before_any_simulation(
    server: ServerProcess, tmp_path: Path
) -> None:
    """A chain and a star of lift-highest: the star's three limbs leave the root's end
    along its axis, through each other; the chain's links only touch at their joints."""
    task = {"name": "lift-highest", "learner": "fast", "train_steps": 64, "eval_episodes": 1}
    body = two_tree_body(task, "star-and-chain", max_trials=2)
    body["space"]["allow_overlaps"] = False  # the example allows them
    with Client(server.url) as client:
        study = client.create_study(body)
        star, chain = client.add_trials(
            study.id,
            [{"params": tree_design(STAR, HALF_PI)}, {"params": tree_design(CHAIN, HALF_PI)}],
        )
        worker = WorkerProcess(server, tmp_path, "overlaps", "--no-render", "--max-jobs", "2")
        try:
            assert worker.wait() == 0, worker.log()
        finally:
            worker.stop()
        star, chain = client.get_trial(star.id), client.get_trial(chain.id)
        assert chain.state == "complete", worker.log()
        assert star.state == "failed", worker.log()
        message = star.message or ""
        assert "links interpenetrate at the rest pose: " in message
        for pair in ("b and c", "b and d", "c and d"):
            assert pair in message, message
        assert "allow_overlaps: true" in message
        assert star.metrics.get("train_steps") is None  # nothing was trained or simulated
        assert client.artifacts(star) == []


def test_a_study_stored_before_the_check_is_evaluated_as_it_was() -> None:
    """Its space has no ``allow_overlaps`` (null): its designs are not checked, so its
    new trials do not start failing; the server stores false for every new study."""
    from adworker.job_robots import check_buildable, decode_job
    from adworker.runner import JobError

    specs = {"front_left.length": 0.2, "front_left_shin.length": 0.2}
    for name in ("front_left", "front_left_shin"):
        specs[f"{name}.joint.axis_theta"] = specs[f"{name}.joint.axis_phi"] = HALF_PI
    job = make_job("quadruped", specs)  # its legs along the torso at rest
    design = decode_job(job)
    for allowed in (None, True):
        check_buildable(job.model_copy(update={"space": space_with(job, allowed)}), design)
    with pytest.raises(JobError, match="torso and back_left"):
        check_buildable(job.model_copy(update={"space": space_with(job, False)}), design)


def space_with(job: Any, allowed: bool | None) -> Any:
    return job.space.model_copy(update={"allow_overlaps": allowed})
