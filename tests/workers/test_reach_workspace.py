"""reach-workspace (issue 60): a fixed-base arm reaches targets drawn per episode from a
ball, on PyBullet and MuJoCo. An arm that holds still, or folds its distal link away,
scores next to nothing; one that holds its tip on the targets scores near 1; the
``fast`` learner finds more of the workspace with an arm that points anywhere than with
one confined to a plane; the targets are the
episode seed's, inside the ball; the fixed base cannot be the distal link."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from pydantic import ValidationError

from adclient.builtin_tasks import ReachWorkspaceOptions
from tests.workers import test_engines

ENGINES = test_engines.ENGINES
engine_env = test_engines.engine_env
"""The fixture of tests/workers/test_engines.py: an env built as the worker builds it."""

POSE = [0.5, 0.4]
"""A pose of the crossed arm (b turned about x, c about y) that points it off the vertical."""


def hold(env, action: list[float], seed: int = 0) -> float:
    env.reset(seed=seed)
    for _ in range(env.episode_steps):
        env.step(np.array(action, dtype=np.float32))
    return env.record.score()


@pytest.mark.parametrize("engine", ENGINES)
def test_holding_still_or_folding_scores_nothing_and_holding_the_targets_scores(
    engine_env, engine: str
) -> None:
    arm = engine_env("reach-workspace", "crossed_chain", engine, episode_steps=16)
    assert hold(arm, [0.0, 0.0]) < 0.01  # straight up, far above the workspace
    assert arm.task_metrics()["distance"] > 0.3
    assert hold(arm, [1.0, -1.0]) < 0.01  # the distal link folded down and away
    # where the arm's tip rests in POSE, a workspace of a millimetre: it holds its tip
    # on every target
    hold(arm, POSE)
    tip = arm.task.tip(arm.snapshot())
    on = engine_env(
        "reach-workspace",
        "crossed_chain",
        engine,
        targets=2,
        episode_steps=24,
        centre=[float(v) for v in tip],
        radius=0.001,
    )
    assert hold(on, POSE) > 0.8
    assert on.task_metrics()["distance"] < 0.02
    # success is read at the end of each target's share: passing over it does not count
    assert hold(on, [0.0, 0.0]) < 0.01


def test_targets_are_the_seeds_and_inside_the_ball(engine_env) -> None:
    arm = engine_env("reach-workspace", "crossed_chain", "pybullet", targets=8, radius=0.3)
    drawn = {}
    for seed in (0, 1, 0):
        arm.reset(seed=seed)
        targets = arm.task.targets.copy()
        assert targets.shape == (8, 3)
        assert np.all(np.linalg.norm(targets - np.array([0.25, 0.25, 0.75]), axis=1) <= 0.3)
        if seed in drawn:
            assert np.array_equal(drawn[seed], targets)
        drawn[seed] = targets
    assert not np.allclose(drawn[0], drawn[1])
    assert len(arm.task.markers(arm.snapshot())) == 8


def test_the_fixed_base_is_no_distal_link_and_targets_fit_the_episode(engine_env) -> None:
    with pytest.raises(ValueError, match="distal_link 'a' is the fixed base"):
        engine_env("reach-workspace", "crossed_chain", "pybullet", distal_link="a")
    with pytest.raises(ValidationError, match="targets \\(9\\) must be at most episode_steps"):
        ReachWorkspaceOptions.model_validate({"targets": 9, "episode_steps": 8})
    with pytest.raises(ValidationError, match="targets"):
        ReachWorkspaceOptions.model_validate({"targets": 17})


def test_the_score_is_the_success_at_each_shares_end_as_documented(engine_env) -> None:
    method = (Path(__file__).resolve().parents[2] / "docs" / "method.md").read_text()
    arm = engine_env("reach-workspace", "crossed_chain", "pybullet", targets=3, tolerance=2.0)
    assert f'"{arm.score_text}"' in method.replace("\n  ", " ")
    arm.reset(seed=2)
    for t in range(arm.episode_steps):  # sweep, so the success changes along the way
        arm.step(np.array([np.sin(t / 5), np.cos(t / 7)], dtype=np.float32))
    metric = arm.record.metric
    steps = arm.episode_steps
    ends = [steps // 3 - 1, 2 * steps // 3 - 1, steps - 1]
    assert arm.record.score() == pytest.approx(np.mean([metric[end] for end in ends]))
    assert len(set(metric)) > 3  # the metric moved, so other steps would score otherwise


@pytest.mark.parametrize("engine", ENGINES)
def test_fast_reaches_more_with_an_arm_that_points_anywhere(engine_env, engine: str) -> None:
    scores = {}
    for design in ("crossed_chain", "parallel_chain"):
        arm = engine_env("reach-workspace", design, engine)
        scores[design] = test_engines.fast_score(arm)
    assert scores["crossed_chain"] > 2 * scores["parallel_chain"] > 0.0, scores
