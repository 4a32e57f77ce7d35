"""One job, start to finish, with no network: decode, URDF, env, train, evaluate, render.

``evaluate_job(job, workdir)`` is a pure function of the job (plus the files it
writes under ``workdir``): the worker loop calls it and reports what it returns,
tests and the benchmark call it directly. Everything it needs is in the job
(DESIGN.md section 2: workers stay stateless).

The score is the mean over ``eval_episodes`` deterministic episodes whose seeds
derive from the task's seed, so re-running a job reproduces its score, and
re-evaluating a design with another task seed draws other training and evaluation
randomness.
"""

from __future__ import annotations

import io
import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from adclient.design import Design, DesignSpace
from adclient.schemas import Job, TaskConfig
from adworker.learners import EpisodeResult, TrainResult, evaluate_policy, get_learner
from adworker.tasks import get_task

EVAL_SEED_STRIDE = 10_000
"""Evaluation episode i of a task with seed s runs with seed (s + 1) * stride + i."""

STAGES = ("decode", "urdf", "env", "train", "evaluate", "render")


class Cancelled(Exception):
    """The worker asked the evaluation to stop (lease lost, or shutting down)."""


class JobError(ValueError):
    """The job cannot be evaluated as given (no design space, unknown task...)."""


@dataclass
class Artifact:
    name: str
    content_type: str
    data: bytes


@dataclass
class Evaluation:
    """What a worker reports for a job: the score, metrics and artifacts."""

    value: float
    metrics: dict[str, float]
    design: Design
    urdf_path: Path
    artifacts: list[Artifact] = field(default_factory=list)
    timings: dict[str, float] = field(default_factory=dict)
    episodes: list[EpisodeResult] = field(default_factory=list)
    train: TrainResult | None = None


def evaluation_seeds(task: TaskConfig) -> list[int]:
    return [(task.seed + 1) * EVAL_SEED_STRIDE + i for i in range(task.eval_episodes)]


def decode_job(job: Job) -> Design:
    from adclient.decode import decode, identity_representation

    if not isinstance(job.space, DesignSpace):
        raise JobError(
            f"task {job.task.name!r} needs a design space (type: design); "
            f"this study's space is of type {job.space.type!r}"
        )
    representation = job.representation or identity_representation(job.space)
    return decode(job.space, representation, job.vector)


def env_options(task: TaskConfig) -> dict[str, Any]:
    options = {k: v for k, v in task.options.items() if k != "learner_kwargs"}
    if task.episode_steps is not None:
        options["episode_steps"] = task.episode_steps
    return options


def evaluate_job(
    job: Job,
    workdir: Path,
    *,
    render: bool = True,
    check: Callable[[], None] | None = None,
) -> Evaluation:
    """Evaluate one job; ``check`` is called between episodes and raises to cancel."""
    from adclient.urdf import design_to_urdf

    check = check or (lambda: None)
    workdir = Path(workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    task = job.task
    timings: dict[str, float] = {}
    started = time.perf_counter()

    def lap(stage: str, since: float) -> float:
        now = time.perf_counter()
        timings[stage] = now - since
        return now

    env_class = get_task(task.name)
    learner_kwargs = task.options.get("learner_kwargs")
    if learner_kwargs is not None and not isinstance(learner_kwargs, dict):
        raise JobError("task.options.learner_kwargs must be a mapping")
    learner = get_learner(task.learner, learner_kwargs)

    t = time.perf_counter()
    design = decode_job(job)
    t = lap("decode", t)
    urdf_path = workdir / "robot.urdf"
    urdf_text = design_to_urdf(design, robot_name="robot")
    urdf_path.write_text(urdf_text)
    t = lap("urdf", t)
    env = env_class(urdf_path, env_options(task))
    try:
        t = lap("env", t)
        steps = task.train_steps if task.train_steps is not None else learner.default_steps
        trained = learner.train(env, steps=steps, seed=task.seed, check=check)
        t = lap("train", t)
        episodes = evaluate_policy(env, trained.policy, evaluation_seeds(task), check=check)
        t = lap("evaluate", t)
        artifacts = [
            Artifact("robot.urdf", "application/xml", urdf_text.encode()),
            Artifact("curve.json", "application/json", _curve_json(job, trained, episodes)),
        ]
        if render:
            # The last evaluation episode has just ended: its final pose.
            artifacts.append(Artifact("robot.png", "image/png", _png(env.render_image())))
        t = lap("render", t)
        sim_steps = env.sim_steps
    finally:
        env.close()
    total = time.perf_counter() - started
    scores = np.array([episode.score for episode in episodes])
    metrics = {
        "score_mean": float(scores.mean()),
        "score_std": float(scores.std()),
        "score_min": float(scores.min()),
        "score_max": float(scores.max()),
        "eval_episodes": float(len(episodes)),
        "train_steps": float(trained.train_steps),
        "sim_steps": float(sim_steps),
        "sim_steps_per_s": float(sim_steps / max(timings["train"] + timings["evaluate"], 1e-9)),
        "time_total_s": total,
    }
    metrics.update({f"time_{stage}_s": timings[stage] for stage in STAGES if stage in timings})
    for key, value in metrics.items():
        if not math.isfinite(value):
            raise ValueError(f"metric {key} is not finite ({value})")
    (workdir / "curve.json").write_bytes(artifacts[1].data)
    for artifact in artifacts:
        if artifact.name == "robot.png":
            (workdir / "robot.png").write_bytes(artifact.data)
    return Evaluation(
        value=float(scores.mean()),
        metrics=metrics,
        design=design,
        urdf_path=urdf_path,
        artifacts=artifacts,
        timings=timings,
        episodes=episodes,
        train=trained,
    )


def _curve_json(job: Job, trained: TrainResult, episodes: list[EpisodeResult]) -> bytes:
    document = {
        "trial_id": job.trial_id,
        "task": job.task.name,
        "learner": job.task.learner,
        "score": "mean over evaluation episodes of the per-step metric's second-half mean",
        "train": trained.curve,
        "evaluation": [
            {
                "seed": episode.seed,
                "score": episode.score,
                "return": episode.episode_return,
                "metric": [round(value, 6) for value in episode.metric],
            }
            for episode in episodes
        ],
    }
    return json.dumps(document, separators=(",", ":")).encode()


def _png(rgb: np.ndarray) -> bytes:
    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(rgb).save(buffer, format="PNG", optimize=True)
    return buffer.getvalue()
