"""The ``mpc`` learner (issue 59) on a real MuJoCo world: its planner does better than
holding still, reproducibly, with either method; a design that cannot do the task scores
under it what it scores under ``fast``; planning leaves the world and the task as they
were; what it cannot run is refused naming why."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from adclient.builtin_learners import MPCOptions
from adworker.learners import evaluate_policy
from adworker.mpc import MPCLearner
from adworker.runner import JobError
from tests.workers import test_engines

engine_env = test_engines.engine_env
"""The fixture of tests/workers/test_engines.py: an env built as the worker builds it."""

SMALL = {"samples": 8, "horizon": 6, "knots": 2, "replan_every": 2}
"""A plan of 48 rollout steps every other step: 800 rollout steps an episode of 32."""


def mpc_scores(env: Any, seeds: list[int], **options: Any) -> list[float]:
    learner = MPCLearner(MPCOptions(**(SMALL | options)))
    trained = learner.train(env, steps=0, seed=0)
    assert trained.train_steps == 0 and trained.checkpoint is None
    return [episode.score for episode in evaluate_policy(env, trained.policy, seeds)]


def holding_still(env: Any, seeds: list[int]) -> list[float]:
    def policy(observation: np.ndarray) -> np.ndarray:
        return np.zeros(env.joint_count, dtype=np.float32)

    return [episode.score for episode in evaluate_policy(env, policy, seeds)]


@pytest.mark.parametrize("method", ["sampling", "cem"])
def test_the_planner_stands_the_arch_up_where_holding_still_does_not(
    engine_env, method: str
) -> None:
    env = engine_env("stand-up", "arch_chain", "mujoco")
    still = holding_still(env, [1])
    before = env.sim_steps
    planned = mpc_scores(env, [1], method=method, cem_iterations=2, cem_elites=2)
    # lying, link b is at its radius (0.04 m); the planner arches it well above that
    assert planned[0] > still[0] + 0.15, (planned, still)
    # its rollouts ran on the engine and count in the job's physics steps: far more
    # than the episode's own 32 x 12
    assert env.sim_steps - before > 10 * env.episode_steps * env.sim.frame_skip
    # an episode depends on its seed alone, not on what ran before it
    assert mpc_scores(env, [1], method=method, cem_iterations=2, cem_elites=2) == planned


def test_a_design_that_cannot_stand_scores_its_radius_under_mpc_as_under_fast(
    engine_env,
) -> None:
    """Axes along the links only roll the cylinders: a planner searching hard for a hop,
    a kick or a glitch that the feet rule would count finds none."""
    env = engine_env("stand-up", "along_links_chain", "mujoco")
    fast = test_engines.fast_score(env)
    planned = float(np.mean(mpc_scores(env, [1, 2])))
    radius = 0.04
    assert fast < radius + 0.01
    assert planned < radius + 0.01, (planned, fast)


SPINNER = {
    "structure_index": 5,
    "root": "a",
    "links": [
        {"name": name, "shape": "cylinder", "length": length, "radius": length / 10, "mass": mass}
        for name, length, mass in (
            ("a", 0.4, 1.0),
            ("b", 0.4, 1.0),
            ("c", 0.35, 0.6),
            ("d", 0.35, 0.6),
            ("e", 0.35, 0.6),
        )
    ],
    "joints": [
        {
            "name": f"{parent}_{child}",
            "parent": parent,
            "child": child,
            "axis": [
                math.sin(theta) * math.cos(phi),
                math.sin(theta) * math.sin(phi),
                math.cos(theta),
            ],
            "axis_theta": theta,
            "axis_phi": phi,
            "position": 1.0,
            "lower": -math.pi / 2,
            "upper": math.pi / 2,
            "effort": 20.0,
            "velocity": 5.0,
        }
        for parent, child, theta, phi in (
            ("a", "b", 1.3675498955141112, 0.3035040974805909),
            ("b", "c", 1.0282714313205616, 0.6919450695110478),
            ("c", "d", 1.7341069018972217, 1.146516249942931),
            ("d", "e", 1.3205670485778331, 1.6560256269361266),
        )
    ],
}
"""A chain of five of examples/multi-structure.yaml's space (bench/engines.py's random
designs of lift-highest, the fourth): with its axes askew, a planner searching hard
finds motions in which MuJoCo's soft contacts give the body energy its motors never put
in, spinning it up until it flies off (its mean top 1,031 m over three episodes, before
the planner ranked such rollouts last)."""


def test_a_design_the_planner_could_fling_off_scores_within_its_reach(engine_env) -> None:
    from adclient.designs import Design

    design = Design.model_validate(SPINNER)
    env = engine_env("lift-highest", design, "mujoco")
    learner = MPCLearner(MPCOptions())
    (score,) = mpc_scores_of(learner, env, [10_000])
    reach = sum(link.length + 2 * link.radius for link in design.links)
    assert 0.0 < score <= reach, score  # no higher than the whole chain standing on end
    assert learner.planner is not None and learner.planner.unphysical > 0


def mpc_scores_of(learner: MPCLearner, env: Any, seeds: list[int]) -> list[float]:
    trained = learner.train(env, steps=0, seed=0)
    return [episode.score for episode in evaluate_policy(env, trained.policy, seeds)]


def test_planning_leaves_the_world_and_the_task_as_they_were(engine_env) -> None:
    """The rollouts run on a copy: the episode's state, the servos' setpoints and the
    task's own state (walk-forward's distance so far) are untouched by a plan."""
    env = engine_env("walk-forward", "arch_chain", "mujoco")
    learner = MPCLearner(MPCOptions(**SMALL))
    policy = learner.train(env, steps=0, seed=0).policy
    observation, _ = env.reset(seed=3)
    for _ in range(4):  # the next step plans (replan_every 2)
        observation, *_ = env.step(policy(observation))
    data = env.sim.data
    state = [np.array(field) for field in (data.qpos, data.qvel, data.act, data.ctrl)]
    task = dict(vars(env.task))
    plans = learner.planner.plans if learner.planner else 0
    policy(observation)
    assert learner.planner is not None and learner.planner.plans == plans + 1
    assert env.sim.data is data
    after = [np.array(field) for field in (data.qpos, data.qvel, data.act, data.ctrl)]
    for was, now in zip(state, after, strict=True):
        np.testing.assert_array_equal(was, now)
    assert vars(env.task) == task
    assert math.isfinite(task["_distance"])


def test_what_mpc_cannot_run_is_refused_naming_why(engine_env) -> None:
    pybullet = engine_env("stand-up", "arch_chain", "pybullet")
    with pytest.raises(JobError, match="'mpc' runs on simulator 'mujoco' alone, not 'pybullet'"):
        MPCLearner(MPCOptions()).train(pybullet, steps=0, seed=0)
    # an episode's plans beyond the budget (the study's episode_steps is the worker's to know)
    long = engine_env("stand-up", "arch_chain", "mujoco", episode_steps=1000)
    with pytest.raises(
        JobError, match=r"128,000 rollout steps, more than max_rollout_steps 65,536"
    ):
        MPCLearner(MPCOptions()).train(long, steps=0, seed=0)
