"""The ``fast`` learner: a non-RL search over constant joint targets (or, for a task with
a gait clock, periodic gaits), judging a design by the best pose or gait it can hold
in about a second (:mod:`adworker.learners` has the RL learners and the interface)."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import ClassVar

import numpy as np

from adworker.learners import Learner, evaluate_policy
from adworker.starts import Policy, Reporting, Start, TrainResult, from_attributes, no_check
from adworker.tasks.base import RobotEnv


class ConstantTargetSearch(Learner):
    """Search over constant joint targets: the best pose the design can reach and hold.

    Three phases over the episode budget. Explore (3/8): the rest pose, then a
    scrambled Halton sequence over [-1, 1]^joints. Refine (3/8): a (1+1) evolution
    strategy around the best so far, its step shrinking on failure. Each of those
    candidates is scored by one episode with the training seed. Validate (1/4): the
    best few candidates run again with other seeds and the best mean wins, so a pose
    that only holds from one starting state (an arch on the edge of tipping over)
    loses to one that holds from all.

    A task with a gait clock (``env.gait_period``, walking) is not done by holding a
    pose: there the same search runs over periodic gaits (:func:`_gait`, three numbers
    per joint), so a design that can move is seen to move.
    """

    name: ClassVar[str] = "fast"
    default_steps: ClassVar[int] = 32 * 32

    def train(
        self,
        env: RobotEnv,
        *,
        steps: int,
        seed: int,
        check: Callable[[], None] = no_check,
        start: Start | None = None,
        keep_checkpoint: bool | None = None,
        reporting: Reporting | None = None,
    ) -> TrainResult:
        """Searches from scratch whatever ``start`` says and keeps no checkpoint (it
        does not transfer, nor pause: a pruner that would pause it prunes it)."""
        reporting = from_attributes(self, start, keep_checkpoint, reporting)[2]
        dims = env.joint_count if env.gait_period is None else 3 * env.joint_count
        policy_of = _constant if env.gait_period is None else _gait
        episodes = max(1, steps // env.episode_steps)
        validate_seeds = 2 if episodes >= 8 else 0
        validate_count = max(1, episodes // 4 // validate_seeds) if validate_seeds else 0
        search = episodes - validate_seeds * validate_count
        explore = max(1, (search + 1) // 2)
        rng = np.random.default_rng(seed)
        curve: list[dict[str, float]] = []
        used = 0

        def score_of(action: np.ndarray, episode_seed: int) -> float:
            nonlocal used
            result = evaluate_policy(env, policy_of(action), [episode_seed], check)[0]
            used += env.episode_steps
            curve.append({"steps": float(used), "score": result.score})
            if reporting is not None and reporting.due <= used < steps:
                # The best candidate's score so far: what the search would pick now.
                reporting.send(used, max(point["score"] for point in curve))
            return result.score

        tried: list[tuple[float, np.ndarray]] = []
        candidates = [np.zeros(dims), *(_halton(explore - 1, dims, rng) * 2.0 - 1.0)]
        for action in candidates:
            tried.append((score_of(action, seed), action))
        best_score, best_action = max(tried, key=lambda pair: pair[0])
        sigma = 0.3
        for _ in range(search - len(candidates)):
            trial = np.clip(best_action + rng.normal(0.0, sigma, dims), -1.0, 1.0)
            score = score_of(trial, seed)
            tried.append((score, trial))
            if score > best_score:
                best_action, best_score = trial, score
                sigma = min(0.5, sigma * 1.5)
            else:
                sigma = max(0.02, sigma * 0.8)
        ranked = sorted(tried, key=lambda pair: -pair[0])
        finalists = _distinct(ranked, validate_count) if validate_count else ranked[:1]
        best_mean = -np.inf
        for first, action in finalists:
            extra = [score_of(action, seed + 1 + k) for k in range(validate_seeds)]
            mean = float(np.mean([first, *extra]))
            if mean > best_mean:
                best_mean, best_action = mean, action
        return TrainResult(
            policy=policy_of(best_action),
            train_steps=used,
            curve=curve,
            info={"best_train_score": float(best_mean), "action": best_action.tolist()},
        )


def _distinct(
    ranked: list[tuple[float, np.ndarray]], count: int, spacing: float = 0.05
) -> list[tuple[float, np.ndarray]]:
    """The best ``count`` candidates, skipping near-duplicates of one already taken."""
    taken: list[tuple[float, np.ndarray]] = []
    for score, action in ranked:
        if all(np.abs(action - other).max() > spacing for _, other in taken):
            taken.append((score, action))
        if len(taken) == count:
            break
    return taken


RAMP_PER_STEP = 0.1
"""How far (in normalised joint range, [-1, 1]) a constant-target policy moves its
command per control step: 0 to 1 in ten steps (about a second at 10 Hz)."""


def _constant(action: np.ndarray, ramp: float = RAMP_PER_STEP) -> Policy:
    """Hold ``action`` as joint targets, approached at a bounded rate from the current pose.

    Every task's observation starts with the joints' normalised positions, in the
    action's own scale, so the ramp needs no state: it commands at most ``ramp`` away
    from where each joint is now. Slamming to the target instead flings a free robot
    about, and the search would then judge the transient rather than the pose.
    """
    fixed = np.asarray(action, dtype=np.float32)
    joints = fixed.shape[0]

    def policy(observation: np.ndarray) -> np.ndarray:
        current = observation[:joints]
        return np.clip(fixed, current - ramp, current + ramp).astype(np.float32)

    return policy


def _gait(gait: np.ndarray) -> Policy:
    """Swing each joint on the env's gait clock: target = offset + amplitude sin(clock +
    phase), from ``gait`` in [-1, 1]^(3 joints): offsets, then amplitudes (mapped onto
    [0, 1]), then phases (onto [-pi, pi]).

    The clock is the observation's last two values, (sin, cos) of its phase (see
    ``RobotEnv``), so the policy needs no state: sin(clock + phase) = sin(clock)
    cos(phase) + cos(clock) sin(phase). All zeros: every joint swinging in step,
    half its range about the middle.
    """
    joints = gait.shape[0] // 3
    offset = gait[:joints]
    amplitude = (gait[joints : 2 * joints] + 1.0) / 2.0
    phase = math.pi * gait[2 * joints :]
    by_sin, by_cos = amplitude * np.cos(phase), amplitude * np.sin(phase)

    def policy(observation: np.ndarray) -> np.ndarray:
        sin, cos = float(observation[-2]), float(observation[-1])
        return np.clip(offset + sin * by_sin + cos * by_cos, -1.0, 1.0).astype(np.float32)

    return policy


def _halton(count: int, dims: int, rng: np.random.Generator) -> np.ndarray:
    """A randomly shifted Halton sequence in [0, 1)^dims (deterministic given rng)."""
    primes = [2, 3, 5, 7, 11, 13, 17, 19, 23, 29, 31, 37, 41, 43, 47, 53]
    if count <= 0:
        return np.zeros((0, dims))
    out = np.empty((count, dims))
    for d in range(dims):
        base = primes[d % len(primes)]
        for i in range(count):
            f, r, n = 1.0, 0.0, i + 1
            while n > 0:
                f /= base
                r += f * (n % base)
                n //= base
            out[i, d] = r
    return (out + rng.random(dims)) % 1.0
