"""Where the server says a trial's robot starts (``GET /api/v1/trials/{id}/spawn``) is
where the worker's simulator puts it: a real adserver, a leased job, and the env the
worker builds from it in real PyBullet."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import httpx
import pybullet
import pytest
import yaml

from adclient.plugins import catalogue
from adclient.schemas import Job, Spawn
from adclient.spawn import CLEARANCE
from adclient.testing.servers import ServerProcess
from adworker.evaluate import task_options
from adworker.job_robots import job_robot
from tests.workers.robots import EXAMPLES

pytestmark = pytest.mark.e2e

ROUNDING = 1e-7
"""PyBullet's poses agree with the pure computation's to about 1e-9 (m, or a
quaternion's parts); a placement that is wrong is off by millimetres or more."""


def study_body(example: str, **changes: Any) -> dict[str, Any]:
    body = yaml.safe_load((EXAMPLES / example).read_text())
    if body["space"]["type"] == "template":
        body["space"]["template"] = (EXAMPLES / body["space"]["template"]).read_text()
    body.update(proposer={"name": "random", "seed": 2}, **changes)
    return body


def engine_pose(job: Job, workdir: Path) -> tuple[Any, Any, dict[str, float], float]:
    """The robot's root frame (position, orientation) and joint positions as the engine
    has them after the worker built the job's env, and the engine's lowest point."""
    design, urdf = job_robot(job)
    path = workdir / f"trial-{job.trial_id}.urdf"
    path.write_text(urdf)
    make_env = catalogue().task(job.task.name).load_factory()
    env = make_env(design=design, urdf_path=path, options=task_options(job.task))
    try:
        robot, cid = env.robot, env.sim.client
        base, turn = pybullet.getBasePositionAndOrientation(robot.body, physicsClientId=cid)
        inertial = robot.sim.dynamics_info(robot.body, -1)
        # the engine poses the base by its inertial frame: back to the root link's frame
        position, orientation = pybullet.multiplyTransforms(
            base,
            turn,
            *pybullet.invertTransform(inertial.inertial_position, inertial.inertial_orientation),
        )
        states = pybullet.getJointStates(robot.body, robot.joint_indices, physicsClientId=cid)
        joints = {joint.name: state[0] for joint, state in zip(robot.joints, states, strict=True)}
        return position, orientation, joints, min(robot.read().bottom)
    finally:
        env.close()


def test_the_served_spawn_pose_is_where_the_worker_puts_the_robot(
    server: ServerProcess, tmp_path: Path
) -> None:
    """A free design (the quadruped, laid on its side along +x), a free template robot
    (as built) and a fixed arm (at the origin): the server's pose is the engine's, to
    rounding; a free robot's lowest point, as the engine reads it, just clears the
    ground. A study no adworker runs has no spawn pose (422), nor has a box study."""
    cases = {
        "quadruped-budget.yaml": False,
        "template-arm.yaml": False,
        "diagonal-gesture.yaml": True,
    }
    with httpx.Client(base_url=server.url, timeout=60) as http:
        for example, fixed in cases.items():
            created = http.post("/api/v1/studies", json=study_body(example))
            assert created.status_code == 201, created.text
            leased = http.post("/api/v1/jobs/lease", json={"worker_id": "spawn-test"})
            assert leased.status_code == 200, leased.text
            job = Job.model_validate(leased.json())
            served = http.get(f"/api/v1/trials/{job.trial_id}/spawn")
            assert served.status_code == 200, served.text
            spawn = Spawn.model_validate(served.json())
            assert spawn.fixed_base is fixed
            position, orientation, joints, lowest = engine_pose(job, tmp_path)
            assert position == pytest.approx(spawn.position, abs=ROUNDING), example
            assert orientation == pytest.approx(spawn.orientation, abs=ROUNDING), example
            assert joints == pytest.approx(spawn.joints, abs=1e-12), example
            if fixed:
                assert spawn.position == (0.0, 0.0, 0.0)
                assert spawn.orientation == (0.0, 0.0, 0.0, 1.0)
            else:
                assert lowest == pytest.approx(CLEARANCE, abs=ROUNDING), example
                assert spawn.position[2] > 0.01
            http.post(f"/api/v1/studies/{created.json()['id']}/stop", json={}).raise_for_status()

        quadruped = study_body("quadruped-budget.yaml", name="no-task")
        del quadruped["task"]
        study = http.post("/api/v1/studies", json=quadruped).json()
        (trial,) = http.post(f"/api/v1/studies/{study['id']}/ask", json={}).json()["trials"]
        refused = http.get(f"/api/v1/trials/{trial['id']}/spawn")
        assert refused.status_code == 422, refused.text
        assert "has no task" in refused.json()["detail"]
        box = {
            "name": "box",
            "direction": "maximize",
            "space": {"type": "box", "params": [{"name": "x", "low": 0.0, "high": 1.0}]},
        }
        study = http.post("/api/v1/studies", json=box).json()
        (trial,) = http.post(f"/api/v1/studies/{study['id']}/ask", json={}).json()["trials"]
        refused = http.get(f"/api/v1/trials/{trial['id']}/spawn")
        assert refused.status_code == 422, refused.text
        assert "box study" in refused.json()["detail"]
