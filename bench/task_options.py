"""What the issue-60 tasks and physics options cost and what ``fast`` finds on them.

    nice -n 5 .venv/bin/python bench/task_options.py [--rounds 5] [--episodes 4]
        [--learn-seeds 2]

Cost: for each engine, each task (stand-up, the baseline, and track-velocity,
reach-workspace and carry-payload) and each arm (``plain``; ``torque``:
``control: torque``; ``randomised``: mass_scale [0.8, 1.2], friction [0.5, 1.5] and
motor_strength [0.7, 1.0]), the process CPU time of a control step (its ``reset``
included, spread over the episode's steps), episodes of a constant random action per
seed; the arms of a task alternate round by round in one process, so they compare within
the run. Learning: the ``fast`` learner's score (1,024 steps, 3 evaluation episodes, as
the worker scores it) on each new task and engine, ``--learn-seeds`` seeds, set against
holding every joint at 0 (what a design that does nothing scores).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

from adclient.plugins import catalogue
from adclient.testing.figures import emit
from adclient.urdf import design_to_urdf
from adworker import designs
from adworker.learners import evaluate_policy

ENGINES = ("pybullet", "mujoco")
TASKS = {
    "stand-up": ("arch_chain", {}),
    "track-velocity": ("arch_chain", {}),
    "reach-workspace": ("crossed_chain", {}),
    "carry-payload": ("arch_chain", {"payload_link": "b"}),
}
ARMS = {
    "plain": {},
    "torque": {"control": "torque"},
    "randomised": {"mass_scale": [0.8, 1.2], "friction": [0.5, 1.5], "motor_strength": [0.7, 1.0]},
}


def build(task: str, engine: str, workdir: Path, **options: Any) -> Any:
    design_name, own = TASKS[task]
    design = getattr(designs, design_name)()
    urdf = workdir / f"{task}-{engine}-{len(list(workdir.iterdir()))}.urdf"
    urdf.write_text(design_to_urdf(design))
    spec = catalogue().task(task)
    return spec.load_factory()(
        design=design,
        urdf_path=urdf,
        options=spec.options.model_validate({**own, **options}),
        simulator=engine,
    )


def step_cost(env: Any, seeds: range) -> float:
    """CPU seconds per control step, resets included."""
    steps = 0
    start = time.process_time()
    for seed in seeds:
        action = np.random.default_rng(seed).uniform(-1, 1, env.joint_count).astype(np.float32)
        env.reset(seed=seed)
        done = False
        while not done:
            *_, terminated, truncated, _ = env.step(action)
            steps += 1
            done = terminated or truncated
    return (time.process_time() - start) / steps


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--episodes", type=int, default=4)
    parser.add_argument("--learn-seeds", type=int, default=2)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        workdir = Path(folder)
        for engine in ENGINES:
            for task in TASKS:
                envs = {arm: build(task, engine, workdir, **opts) for arm, opts in ARMS.items()}
                costs: dict[str, list[float]] = {arm: [] for arm in ARMS}
                for round_ in range(args.rounds):
                    seeds = range(round_ * args.episodes, (round_ + 1) * args.episodes)
                    for arm, env in envs.items():
                        costs[arm].append(step_cost(env, seeds))
                for env in envs.values():
                    env.close()
                plain = float(np.median(costs["plain"]))
                for arm, values in costs.items():
                    median = float(np.median(values))
                    print(f"{engine} {task} {arm}: {median * 1e6:.0f} us/step", file=sys.stderr)
                    emit(f"{task}.{engine}.{arm}_us", median * 1e6, higher_is_better=False)
                    if arm != "plain":
                        emit(
                            f"{task}.{engine}.{arm}_over_plain",
                            median / plain,
                            higher_is_better=False,
                            unit="x",
                        )
        fast = catalogue().learner("fast").load_factory()
        for engine in ENGINES:
            for task in ("track-velocity", "reach-workspace", "carry-payload"):
                scores, still = [], []
                for seed in range(args.learn_seeds):
                    env = build(task, engine, workdir)
                    trained = fast(None).train(env, steps=1024, seed=seed)
                    evaluation = [1000 + seed + i for i in range(3)]
                    scores.append(
                        np.mean([e.score for e in evaluate_policy(env, trained.policy, evaluation)])
                    )
                    zero = np.zeros(env.joint_count, dtype=np.float32)
                    still.append(
                        np.mean(
                            [
                                e.score
                                for e in evaluate_policy(env, lambda o, zero=zero: zero, evaluation)
                            ]
                        )
                    )
                    env.close()
                print(
                    f"{engine} {task}: fast {np.round(scores, 3)}, still {np.round(still, 3)}",
                    file=sys.stderr,
                )
                emit(f"{task}.{engine}.fast_score", float(np.mean(scores)), higher_is_better=True)
                emit(f"{task}.{engine}.still_score", float(np.mean(still)), higher_is_better=True)


if __name__ == "__main__":
    main()
