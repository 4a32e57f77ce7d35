"""One side of bench/evaluation.py's split comparison: the CPU cost of ``env.step``.

    python bench/step_cost.py [--whole-body-clamp]    # then one JSON request per line

Runs with whatever harness the interpreter imports: the installed one, or the
pre-split code put first on PYTHONPATH by bench/evaluation.py (``--part split``). It
imports only what both harnesses have, and builds each env the way its harness does.
It first prints where that harness was imported from; then, for each request
``{"case": "task/design", "episode": k}``, it runs episode k (seed k, one constant
random action drawn from seed k) and prints the thread CPU seconds of its steps (reset
excluded) and its metric trace, so the two sides can be checked to simulate the same.
A long-lived process per side lets the caller alternate the sides episode by episode.

``--whole-body-clamp`` puts back, in the installed harness, the joint speed limit the
pre-split code used (changeDynamics maxJointVelocity: Bullet's one velocity clamp of
the whole body, since replaced by each motor's limit, commit 35fc49d), so that it
simulates exactly what the old code did and its cost is the harness's alone.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

from adclient.urdf import design_to_urdf
from adworker import designs

CASES = [
    "stand-up/arch_chain",
    "stand-up/along_links_chain",
    "diagonal-gesture/crossed_chain",
    "lift-highest/arch_chain",
]


def build_env(case: str, workdir: Path, whole_body_clamp: bool) -> Any:
    task, design_name = case.split("/")
    design = getattr(designs, design_name)()
    urdf = workdir / f"{task}-{design_name}.urdf"
    urdf.write_text(design_to_urdf(design))
    import adworker.tasks

    if hasattr(adworker.tasks, "get_task"):
        # The pre-split harness: one env class per task, built from the URDF alone.
        return adworker.tasks.get_task(task)(urdf)
    from adclient.plugins import catalogue

    spec = catalogue().task(task)
    env = spec.load_factory()(design=design, urdf_path=urdf, options=spec.options())
    if whole_body_clamp:
        import pybullet

        robot, cid = env.robot, env.sim.client
        for joint in robot.joints:
            pybullet.changeDynamics(
                robot.body, joint.index, maxJointVelocity=joint.velocity, physicsClientId=cid
            )
            pybullet.setJointMotorControl2(
                robot.body,
                joint.index,
                pybullet.POSITION_CONTROL,
                targetPosition=0.0,
                force=joint.effort,
                maxVelocity=1e30,
                physicsClientId=cid,
            )
        robot._saved_state = env.sim.save_state()
    return env


def run_episode(env: Any, episode: int) -> dict[str, Any]:
    joints = env.action_space.shape[0]
    action = np.random.default_rng(episode).uniform(-1, 1, joints).astype(np.float32)
    env.reset(seed=episode)
    started = time.thread_time()
    for _ in range(env.episode_steps):
        env.step(action)
    seconds = time.thread_time() - started
    return {"seconds": seconds, "steps": env.episode_steps, "metric": list(env.record.metric)}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--whole-body-clamp", action="store_true")
    args = parser.parse_args()
    import adworker.tasks

    print(json.dumps({"code": str(Path(adworker.tasks.__file__).parent)}), flush=True)
    envs: dict[str, Any] = {}
    with tempfile.TemporaryDirectory() as scratch:
        for line in sys.stdin:
            request = json.loads(line)
            case = request["case"]
            if case not in envs:
                envs[case] = build_env(case, Path(scratch), args.whole_body_clamp)
            print(json.dumps(run_episode(envs[case], request["episode"])), flush=True)
        for env in envs.values():
            env.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
