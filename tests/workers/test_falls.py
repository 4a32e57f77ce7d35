"""Designs that cheat score no better than honest ones (issue 60), on both engines: a
quadruped that throws itself forward onto its side has not walked (walk-forward counts no
progress while the body has fallen, and reports ``task.fell``), while an inchworm that
pitches its end link up and down still walks; an arch that hops or flails scores less on
stand-up and lift-highest than one that holds its pose. (A link hidden in another is
refused before any simulation, whatever the task: tests/workers/test_overlaps_e2e.py.)"""

from __future__ import annotations

import itertools
import math
from typing import Any

import numpy as np
import pytest

from adclient.designs import Design, Joint, Link
from adworker.learners import evaluate_policy
from adworker.tasks.snapshot import quaternion_matrix
from tests.workers import test_engines
from tests.workers.robots import HALF_PI

ENGINES = test_engines.ENGINES
engine_env = test_engines.engine_env
"""The fixture of tests/workers/test_engines.py: an env built as the worker builds it."""


def standing_quadruped() -> Design:
    """A box torso on four two-link legs, each thigh turned down off the torso's end
    (offset pitch a quarter turn) and splayed sideways (offset roll), so it stands on
    them: a body that can fall onto its side."""
    links = [Link(name="torso", shape="box", length=0.5, radius=0.08, mass=2.0)]
    joints = []
    for leg, position in (
        ("front_left", 1.0),
        ("front_right", 1.0),
        ("back_left", 0.0),
        ("back_right", 0.0),
    ):
        side = 1.0 if leg.endswith("left") else -1.0
        links += [
            Link(name=leg, shape="cylinder", length=0.2, radius=0.03, mass=0.3),
            Link(name=f"{leg}_shin", shape="cylinder", length=0.2, radius=0.025, mass=0.2),
        ]
        for parent, child, offset in (
            ("torso", leg, {"offset_pitch": HALF_PI, "offset_roll": 0.6 * side}),
            (leg, f"{leg}_shin", {}),
        ):
            joints.append(
                Joint(
                    name=f"{parent}_{child}",
                    parent=parent,
                    child=child,
                    axis=(math.cos(HALF_PI), 1.0, math.cos(HALF_PI)),
                    axis_theta=HALF_PI,
                    axis_phi=HALF_PI,
                    position=position if parent == "torso" else 1.0,
                    lower=-HALF_PI,
                    upper=HALF_PI,
                    effort=10.0,
                    velocity=6.0,
                    **offset,
                )
            )
    return Design(structure_index=0, root="torso", links=links, joints=joints)


DIVE = (
    np.array([0.47, -0.09, -0.65, -0.32, 0.22, -0.33, -0.72, -0.89]),
    np.array([0.39, 0.73, 0.35, 0.41, 0.8, 0.64, 0.98, 0.83]),
    np.array([5.9, 3.2, 4.86, 6.28, 0.07, 2.95, 4.67, 1.45]),
)
"""A gait (offset, amplitude and phase per joint on the task's clock, as the fast learner
searches) with which :func:`standing_quadruped` throws itself forward and lands on its
side, on either engine: found by a random search of gaits for ones that end rolled over
after moving forward."""


def run(env: Any, gait: tuple[np.ndarray, np.ndarray, np.ndarray] | None) -> tuple[float, float]:
    """One episode of ``gait`` (None: every joint held at 0): its score and its return."""
    observation, _ = env.reset(seed=0)
    env.tilts = []
    up = quaternion_matrix(env.snapshot().orientation(0)).T @ np.array([0.0, 0.0, 1.0])
    total = 0.0
    for _ in range(env.episode_steps):
        if gait is None:
            action = np.zeros(env.joint_count)
        else:
            offset, amplitude, phase = gait
            clock = math.atan2(observation[-2], observation[-1])
            action = np.clip(offset + amplitude * np.sin(clock + phase), -1.0, 1.0)
        observation, reward, *_ = env.step(action.astype(np.float32))
        total += reward
        now = quaternion_matrix(env.snapshot().orientation(0)) @ up
        env.tilts.append(math.degrees(math.acos(min(1.0, now[2]))))  # the root's, from up
    return env.record.score(), total


@pytest.mark.parametrize("engine", ENGINES)
def test_a_quadruped_that_dives_onto_its_side_has_not_walked(engine_env, engine: str) -> None:
    # without the fall check (a fall angle of 90 degrees never calls it fallen) the dive
    # scores as the did: the ground it covered falling
    unchecked = engine_env("walk-forward", standing_quadruped(), engine, fall_angle=90.0)
    assert run(unchecked, DIVE)[0] > 0.2
    assert unchecked.task_metrics() == {"fell": 0.0}

    walker = engine_env("walk-forward", standing_quadruped(), engine)
    still, _ = run(walker, None)
    assert abs(still) < 0.01 and walker.task_metrics() == {"fell": 0.0}
    dive, dive_return = run(walker, DIVE)
    assert dive <= 0.0 <= still + 0.01  # no better than standing still
    assert walker.task_metrics() == {"fell": 1.0}  # and marked fallen
    # the metric counted the dive's progress while upright, none once it lay on its side;
    # the reward is the metric's change, so the fall took back what it had covered
    metric = walker.record.metric
    assert max(metric) > 0.05 and metric[-1] == 0.0
    assert dive_return == pytest.approx(dive, abs=1e-9)


@pytest.mark.parametrize("engine", ENGINES)
def test_an_inchworm_pitching_its_end_link_up_has_not_fallen(engine_env, engine: str) -> None:
    """Pitching is how a chain lying on the ground moves: only a roll onto the side, or
    a turn over onto the back, is a fall."""
    from tests.workers.test_walk_forward import ACROSS

    chain = engine_env("walk-forward", ACROSS, engine)
    unchecked = engine_env("walk-forward", ACROSS, engine, fall_angle=90.0)
    swing = (np.zeros(3), np.ones(3), np.zeros(3))  # every joint follows the clock
    score, _ = run(chain, swing)
    assert chain.task_metrics() == {"fell": 0.0}
    assert score == run(unchecked, swing)[0]
    assert abs(score) > 0.02  # it moved
    assert max(chain.tilts) > 50.0  # its root pitched past the fall angle, up and down


def flail(env: Any, period: int) -> float:
    """The mean score of two episodes of every joint thrown from one end of its range to
    the other every ``period`` control steps: hops, kicks and falls."""
    steps = itertools.count()

    def policy(observation: np.ndarray) -> np.ndarray:
        sign = 1.0 if (next(steps) // period) % 2 == 0 else -1.0
        return np.full(env.joint_count, sign, dtype=np.float32)

    return float(np.mean([episode.score for episode in evaluate_policy(env, policy, [1, 2])]))


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize("task", ["stand-up", "lift-highest"])
def test_hopping_and_flailing_score_less_than_holding_a_pose(
    engine_env, task: str, engine: str
) -> None:
    """A jump counts only while it lasts and a lifted foot counts 0: throwing the arch
    about (its best hop scored 0.03 to 0.38 where its held pose scored 0.35 to 0.44)
    never beats the pose the fast learner holds."""
    env = engine_env(task, "arch_chain", engine)
    held = test_engines.fast_score(env)
    assert held > 0.3
    assert max(flail(env, period) for period in (1, 2, 4)) < held - 0.03
