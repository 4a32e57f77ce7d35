"""One job, start to finish, with no network: decode, URDF, env, train, evaluate, render.

``evaluate_job(job, workdir)`` is a pure function of the job (plus the files it
writes under ``workdir``): the worker loop calls it and reports what it returns,
tests and the benchmark call it directly. Everything it needs is in the job
(docs/method.md, "The loop": workers stay stateless).

Besides the score it reports secondary metrics a study may optimise or constrain:
``mass`` and ``link_length`` of the design as built, and ``effort`` and ``energy`` of
its motors over the evaluation episodes (:class:`adworker.tasks.robot.MotorMeter`;
docs/worker.md, "Metrics a task reports"), and the task's own as ``task.<name>``
(:mod:`adworker.task_metrics`).

The score is the mean over ``eval_episodes`` deterministic episodes whose seeds
derive from the task's seed, so re-running a job reproduces its score, and
re-evaluating a design with another task seed draws other training and evaluation
randomness.
"""

from __future__ import annotations

import functools
import io
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import numpy as np
from pydantic import BaseModel, ValidationError

from adclient.design import DesignSpace
from adclient.designs import Design
from adclient.plugins import (
    SIMULATORS,
    PluginError,
    TaskOptions,
    catalogue,
    learner_budget_problems,
)
from adclient.pruning import CHECKPOINT_ARTIFACT
from adclient.schemas import (
    CURVE_ARTIFACT,
    REPLAY_ARTIFACT,
    SHARED_ARTIFACT,
    Job,
    TaskConfig,
    option_problems,
)
from adworker import shared_weights
from adworker.curves import env_score_text, evaluation_curve
from adworker.job_robots import check_buildable, job_robot
from adworker.learners import (
    EpisodeResult,
    Learner,
    Policy,
    Reporting,
    TrainResult,
    evaluate_policy,
)
from adworker.replay import ReplayRecorder
from adworker.runner import (
    SHARED_FILE,
    TRANSFER_FILE,
    Artifact,
    JobError,
    Outcome,
    Pruned,
    Report,
    factory_problem,
    no_report,
)
from adworker.starts import SCRATCH, Resume, Shared, Start, Warm, train_learner
from adworker.task_metrics import merge_task_metrics
from adworker.tasks.base import RobotEnv

log = logging.getLogger("adworker")

EVAL_SEED_STRIDE = 10_000
"""Evaluation episode i of a task with seed s runs with seed (s + 1) * stride + i."""

STAGES = ("decode", "urdf", "env", "train", "evaluate", "render")


@dataclass
class Evaluation:
    """What a worker reports for a job: the score, metrics and artifacts."""

    value: float
    metrics: dict[str, float]
    design: Design | None
    """None for a template study's robot (its URDF is all there is)."""
    urdf_path: Path
    artifacts: list[Artifact] = field(default_factory=list)
    timings: dict[str, float] = field(default_factory=dict)
    episodes: list[EpisodeResult] = field(default_factory=list)
    train: TrainResult | None = None
    transfer_from: int | None = None
    """The trial whose controller this one started from (``job.transfer``), if it did."""
    shared_start: bytes | None = None
    """A shared-controller job: the weights it started from (``Outcome.shared_start``)."""


def evaluation_seeds(task: TaskConfig) -> list[int]:
    return [(task.seed + 1) * EVAL_SEED_STRIDE + i for i in range(task.eval_episodes)]


def template_metrics(urdf: str) -> dict[str, float]:
    """What a template's robot is before any physics: ``mass`` (kg, the sum of its
    links' inertial masses)."""
    from adclient.urdf_model import read_urdf

    return {"mass": read_urdf(urdf).mass}


def design_metrics(design: Design, space: DesignSpace | None = None) -> dict[str, float]:
    """What a design is, before any physics: ``mass`` (kg, the sum of its links' masses,
    those PyBullet simulates), ``link_length`` (m, the sum of its links' lengths) and,
    when its space has catalogues, the chosen components' entries summed per catalogue
    (``motors.cost``)."""
    from adclient.decode import design_catalogue_totals
    from adclient.urdf import design_link_length, design_mass

    metrics = {"mass": design_mass(design), "link_length": design_link_length(design)}
    if space is not None and space.catalogues:
        metrics.update(design_catalogue_totals(space, design))
    return metrics


def task_options(task: TaskConfig) -> TaskOptions:
    """The task's options model filled in from the job (``task.episode_steps`` wins over
    ``options.episode_steps``); a JobError for a task not installed here."""
    options = dict(task.options)
    if task.episode_steps is not None:
        options["episode_steps"] = task.episode_steps
    try:
        return catalogue().task(task.name).options.model_validate(options)
    except PluginError as error:
        raise JobError(str(error)) from None


def make_learner(task: TaskConfig, options: TaskOptions) -> Learner:
    """The job's learner, given ``options.learner_kwargs`` checked by its options model."""
    try:
        spec = catalogue().learner(task.learner)
    except PluginError as error:
        raise JobError(str(error)) from None
    if spec.options is None:
        if options.learner_kwargs is not None:
            raise JobError(f"learner {task.learner!r} takes no learner_kwargs")
        learner: Learner = spec.load_factory()(None)
    else:
        learner = spec.load_factory()(learner_options(task, options, spec.options))
    return learner


def learner_options(task: TaskConfig, options: TaskOptions, model: type[BaseModel]) -> BaseModel:
    """The job's ``learner_kwargs`` as its learner's options model reads them, within its
    budget for the job's steps; a JobError naming each option that is not (a study stored
    before its learner's options were checked at creation)."""
    owner = f"learner {task.learner!r}"
    try:
        checked = model.model_validate(options.learner_kwargs or {})
    except ValidationError as error:
        problems = option_problems(error, model, owner, prefix="task.options.learner_kwargs")
        raise JobError(f"{'; '.join(problems)}: refused by this worker") from None
    problems = learner_budget_problems(checked, task.train_steps, task.transfer_steps)
    if problems:
        listed = "; ".join(f"task.options.learner_kwargs: {p} ({owner})" for p in problems)
        raise JobError(f"{listed}: refused by this worker")
    return checked


def env_factory(task: TaskConfig) -> Callable[..., Any]:
    """The task's environment factory, building on the engine the study names
    (``task.simulator``; the factory is passed ``simulator=`` only for another than the
    default); a JobError for an engine the task does not declare."""
    spec = catalogue().task(task.name)
    if task.simulator not in spec.simulators:
        raise JobError(
            f"task {task.name!r} does not run on simulator {task.simulator!r} "
            f"(its simulators: {', '.join(spec.simulators)})"
        )
    factory = spec.load_factory()
    if task.simulator == SIMULATORS[0]:
        return factory
    return functools.partial(factory, simulator=task.simulator)


def evaluate_job(
    job: Job,
    workdir: Path,
    *,
    render: bool = True,
    check: Callable[[], None] | None = None,
    report: Report | None = None,
) -> Evaluation:
    """Evaluate one job; ``check`` is called between episodes and raises to cancel.
    With ``report`` and a study pruner, the learner reports its policy's score every
    ``pruner.report_every`` steps (``report`` raises ``Pruned`` to stop it). A promoted
    job (``job.resume``) trains on from the checkpoint file of that name in ``workdir``."""
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

    options = task_options(task)
    make_env = env_factory(task)
    learner = make_learner(task, options)
    start: Start = SCRATCH
    if job.resume is not None:  # a promoted trial: the worker put its checkpoint here
        start = Resume((workdir / job.resume.artifact).read_bytes())
    elif job.transfer is not None and (workdir / TRANSFER_FILE).exists():
        checkpoint = (workdir / TRANSFER_FILE).read_bytes()
        start = Warm(checkpoint, task.warm_steps(learner.default_steps))
    elif task.transfer == "shared":
        start = shared_start(job, workdir, learner)

    t = time.perf_counter()
    design, urdf_text = job_robot(job)
    check_buildable(job, design)
    t = lap("decode", t)
    urdf_path = workdir / "robot.urdf"
    urdf_path.write_text(urdf_text)
    t = lap("urdf", t)
    env = make_env(design=design, urdf_path=urdf_path, options=options)
    interim_envs: list[Any] = []
    try:
        t = lap("env", t)
        budget = task.train_steps if task.train_steps is not None else learner.default_steps
        # a promoted trial trains on to the budget it paused under (a warm start's), never
        # past the most this study asks of a design (the pause's budget is a worker's word)
        steps = budget
        if job.resume is not None and job.resume.budget is not None:
            steps = min(job.resume.budget, max(budget, task.warm_steps(learner.default_steps)))
        reporting = None
        if report is not None and job.pruner.name != "none":

            def interim(policy: Policy) -> float:
                """The task's evaluation episodes on an env apart from training's."""
                if not interim_envs:
                    interim_envs.append(
                        make_env(design=design, urdf_path=urdf_path, options=options)
                    )
                episodes = evaluate_policy(interim_envs[0], policy, evaluation_seeds(task), check)
                return float(np.mean([episode.score for episode in episodes]))

            # on the from-scratch budget's steps, warm or resumed: every attempt of every
            # design reports at the same steps, so ASHA's rungs compare like with like
            every = job.pruner.report_every or max(1, budget // 10)
            reporting = Reporting(every=every, evaluate=interim, report=report)
        try:
            trained = train_learner(
                learner,
                env,
                steps=steps,
                seed=task.seed,
                check=check,
                start=start,
                keep_checkpoint=task.transfer == "nearest",
                reporting=reporting,
            )
        except Pruned as stopped:
            stopped.budget = steps
            if isinstance(start, Warm) and getattr(learner, "warm_problem", None) is None:
                stopped.budget = start.steps
                stopped.transfer_from = _transfer_from(job)
                stopped.metrics.update(_transfer_metrics(job, start))
            raise
        t = lap("train", t)
        # A task env of this package meters its motors; a plugin's env may not.
        meter_motors = getattr(env, "meter_motors", None)
        meter = meter_motors() if callable(meter_motors) else None
        # A task env of this package has a robot to replay; a plugin's env may not.
        recorder = ReplayRecorder(env) if _replayable(env) else None
        episodes = evaluate_policy(
            cast(RobotEnv, recorder or env), trained.policy, evaluation_seeds(task), check=check
        )
        t = lap("evaluate", t)
        artifacts = [
            Artifact("robot.urdf", "application/xml", urdf_text.encode()),
            Artifact(CURVE_ARTIFACT, "application/json", _curve_json(job, trained, episodes, env)),
        ]
        replay = None if recorder is None else recorder.replay(trial_id=job.trial_id)
        if replay is not None:
            artifacts.append(Artifact(REPLAY_ARTIFACT, "application/json", replay.to_json()))
        if trained.checkpoint is not None:
            artifacts.append(Artifact(CHECKPOINT_ARTIFACT, "application/zip", trained.checkpoint))
        if trained.shared is not None and trained.shared_start is not None:
            update = shared_weights.encode(trained.shared)
            artifacts.append(Artifact(SHARED_ARTIFACT, "application/octet-stream", update))
        if render:
            # The last evaluation episode has just ended: its final pose.
            artifacts.append(Artifact("robot.png", "image/png", _png(env.render_image())))
        t = lap("render", t)
        sim_steps = env.sim_steps + sum(other.sim_steps for other in interim_envs)
    finally:
        env.close()
        for other in interim_envs:
            other.close()
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
        **(
            template_metrics(urdf_text)
            if design is None
            else design_metrics(design, job.space if isinstance(job.space, DesignSpace) else None)
        ),
    }
    if trained.warm_started and isinstance(start, Warm):
        metrics.update(_transfer_metrics(job, start))
    if isinstance(start, Shared):  # the version it trained from: 0, the initial weights
        metrics["shared_from"] = float(start.version or 0) if trained.warm_started else 0.0
        metrics["transfer_steps"] = float(start.steps if trained.warm_started else steps)
    if meter is not None:
        metrics["effort"] = float(meter.effort)
        metrics["energy"] = float(meter.energy)
    metrics.update({f"time_{stage}_s": timings[stage] for stage in STAGES if stage in timings})
    metrics = merge_task_metrics(metrics, [episode.task_metrics for episode in episodes])
    for key, value in metrics.items():
        if not math.isfinite(value):
            raise ValueError(f"metric {key} is not finite ({value})")
    (workdir / CURVE_ARTIFACT).write_bytes(artifacts[1].data)
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
        transfer_from=_transfer_from(job)
        if trained.warm_started and isinstance(start, Warm)
        else None,
        shared_start=(
            None if trained.shared_start is None else shared_weights.encode(trained.shared_start)
        ),
    )


def shared_start(job: Job, workdir: Path, learner: Learner) -> Shared:
    """Where a ``task.transfer: shared`` job starts: the version the worker downloaded
    (``SHARED_FILE``) for the warm budget, else (none yet, or one that does not load:
    the reason logged) the study's initial weights for the full budget."""
    task = job.task
    weights = None
    path = workdir / SHARED_FILE
    if job.shared is not None and path.exists():
        try:
            weights = shared_weights.decode(path.read_bytes())
        except shared_weights.SharedWeightsError as error:
            log.warning(
                "trial %s: shared controller version %d does not load (%s): starting from "
                "the study's initial weights",
                job.trial_id,
                job.shared.version,
                error,
            )
    if weights is None:
        budget = task.train_steps if task.train_steps is not None else learner.default_steps
        return Shared(weights=None, steps=budget, seed=task.seed)
    assert job.shared is not None
    return Shared(
        weights=weights,
        steps=task.warm_steps(learner.default_steps),
        seed=task.seed,
        version=job.shared.version,
        carries=task.shared_carries,
    )


def _transfer_from(job: Job) -> int:
    assert job.transfer is not None
    return job.transfer.trial_id


def _transfer_metrics(job: Job, start: Warm) -> dict[str, float]:
    """What a warm-started trial shows its users: its budget and its distance to the
    design it started from."""
    assert job.transfer is not None
    return {
        "transfer_steps": float(start.steps),
        "transfer_distance": job.transfer.distance,
    }


class TaskRunner:
    """Runs jobs of the installed tasks whose environments load here: ``adworker``'s
    default runner. A task whose factory fails to import (its simulator missing) is not
    leased, so a worker that has it takes its trials; nor is a study whose learner does
    not load."""

    def __init__(self, *, render: bool = True) -> None:
        self.render = render
        installed = catalogue()
        for key, reason in sorted(installed.broken.items()):
            log.warning("plugin %s does not load: %s", key, reason)
        self._tasks: list[str] = []
        for name, spec in sorted(installed.tasks.items()):
            problem = factory_problem(spec)
            if problem is None:
                self._tasks.append(name)
            else:
                log.warning(
                    "task %s: its environment does not load (%s); not leasing it", name, problem
                )
        self._learners: list[str] = []
        for name, learner in sorted(installed.learners.items()):
            problem = factory_problem(learner)
            if problem is None:
                self._learners.append(name)
            else:
                log.warning("learner %s does not load (%s); not leasing its studies", name, problem)

    def tasks(self) -> list[str]:
        return list(self._tasks)

    def learners(self) -> list[str]:
        return list(self._learners)

    def __call__(
        self, job: Job, workdir: Path, check: Callable[[], None], report: Report = no_report
    ) -> Outcome:
        evaluation = evaluate_job(job, workdir, render=self.render, check=check, report=report)
        timings = ", ".join(
            f"{stage} {seconds:.2f}" for stage, seconds in evaluation.timings.items()
        )
        spread = evaluation.metrics["score_std"]
        return Outcome(
            evaluation.value,
            evaluation.metrics,
            evaluation.artifacts,
            summary=f"score {evaluation.value:.4f} ± {spread:.4f} ({timings} s)",
            transfer_from=evaluation.transfer_from,
            shared_start=evaluation.shared_start,
        )


def _curve_json(
    job: Job, trained: TrainResult, episodes: list[EpisodeResult], env: object
) -> bytes:
    """The trial's ``curve.json`` (:class:`adclient.schemas.Curve`); its score text the
    rule ``env`` declares it scores the episodes with (its task's ``score_rule``)."""
    return evaluation_curve(job, trained, episodes, env_score_text(env)).to_json()


def _replayable(env: object) -> bool:
    """An env whose robot the replay can read: this package's task envs."""
    robot = getattr(env, "robot", None)
    return (
        callable(getattr(env, "snapshot", None))
        and hasattr(getattr(env, "sim", None), "control_period")
        and hasattr(robot, "spawn")
        and hasattr(robot, "joints")
    )


def _png(rgb: np.ndarray) -> bytes:
    from PIL import Image

    buffer = io.BytesIO()
    Image.fromarray(rgb).save(buffer, format="PNG", optimize=True)
    return buffer.getvalue()
