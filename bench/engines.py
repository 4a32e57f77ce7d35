"""Engines (issue 59): control steps per CPU-second of each simulator on the same design,
random actions (the limit a learner could reach) and stable-baselines3 PPO with one env
as the worker configures it (today's baseline arm), and the same on batched worlds
(adworker.batched: PPO's ``n_envs``), in one run on one core.

    python bench/engines.py [--tasks stand-up,walk-forward] [--steps 3000] \\
        [--ppo-steps 4096] [--worlds 8,16,32] [--agree 0] [--learn 0] \\
        [--learn-tasks stand-up] [--core 0] [--json FILE]

Per task and engine: ``random``, control steps per CPU-second of ``env.step`` with a new
uniform random action each step (resets counted, as an episode's end needs one); and,
unless ``--ppo-steps 0``, ``ppo``, env steps per CPU-second of the ``ppo`` learner's
``train`` (adworker.learners, the worker's PPO: its first training in the process is
left out of the figure, as torch's set-up is a worker's once). Each is the process's CPU
time, one thread (``OMP_NUM_THREADS=1``, torch on one thread), the process pinned to
``--core``. Designs: stand-up's arch of three 0.4 m links (bench/shared_policy.py's
``make_env('stand-up', 0)``), walk-forward's quadruped of examples/quadruped.yaml (its
searched lengths at 0.2 m, its axes across the body), lift-highest's chain of four.

``--agree N``: N random designs of stand-up (examples/stand-up.yaml's space) and of
lift-highest (examples/multi-structure.yaml's, several trees), each scored with the
``fast`` learner on both engines as the worker scores it; Spearman's rank correlation of
the two engines' scores, per task.

``--worlds N,...`` (unless empty): per task and engine, ``random-batch``, control steps
per CPU-second of a batch of the largest N worlds stepped with random actions (the
batch's limit); ``physics-batch``, the same batch's engine alone (each world's motor
command and physics steps, no state read, task or observation: the limit of
vectorising those); ``ppo-N``, the ``ppo`` learner (stable-baselines3) with ``n_envs:
N`` on the same budget (``--ppo-steps`` env steps, all worlds together; the same
rollout of 512 samples, minibatches and epochs as one env); and ``ppo-batch-N``, the
``ppo-batch`` learner (adworker.batch_ppo, the worker's own PPO on the batch) with
``n_envs: N``, its other settings its defaults, on the same budget. Then issue 59's
goals per task and batched learner: its best arm on MuJoCo and on PyBullet over today's
baseline (SB3 PPO, one env, PyBullet), the learner's share of that arm's step,
``1 - ppo / random-batch``, each arm's gradient updates per sample, and the engine
alone on the batch over the baseline (no learner on that engine could go past it).

``--learn N``: what the learners learn, not how fast: each of ``--learn-tasks``'
designs trained on ``ppo``'s default budget (12,288 steps) by ``ppo`` with one env and
with ``n_envs: 16``, and by ``ppo-batch`` at its defaults, seeds 0 to N-1, on each
engine, each scored as the worker scores it (3 evaluation episodes); the mean score per
task, engine and arm, its CPU-seconds and its gradient updates per sample.

Prints a table and one ``BENCH`` line per figure (``bench/compare.py``); ``--json``
writes the rows.
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

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from adclient.testing.figures import emit  # noqa: E402

ENGINES = ("pybullet", "mujoco")
TASKS = ("stand-up", "walk-forward", "lift-highest")
HALF_PI = 1.5707963267948966


def design_of(task: str) -> Any:
    from adworker import designs

    if task == "stand-up":
        return designs.arch_chain()
    if task == "lift-highest":
        return designs.tree_design(
            [("a", "b"), ("b", "c"), ("c", "d")],
            {"b": (HALF_PI, HALF_PI), "c": (HALF_PI, HALF_PI), "d": (HALF_PI, 0.0)},
            length=0.4,
        )
    return quadruped()


def quadruped() -> Any:
    """examples/quadruped.yaml's robot, its searched specs at mid-range."""
    import yaml

    from adclient.decode import decode, identity_representation
    from adclient.encode import encode
    from adclient.schemas import StudyCreate

    study = StudyCreate.model_validate(
        yaml.safe_load((ROOT / "examples" / "quadruped.yaml").read_text())
    )
    specs = {
        "front_left.length": 0.2,
        "front_left_shin.length": 0.2,
        "front_left.joint.axis_theta": HALF_PI,
        "front_left.joint.axis_phi": HALF_PI,
        "front_left_shin.joint.axis_theta": HALF_PI,
        "front_left_shin.joint.axis_phi": HALF_PI,
    }
    representation = identity_representation(study.space)
    return decode(study.space, representation, encode(study.space, representation, specs))


def make_env(task: str, engine: str, folder: Path) -> Any:
    from adclient.plugins import catalogue
    from adclient.urdf import design_to_urdf

    design = design_of(task)
    path = folder / f"{task}-{engine}.urdf"
    path.write_text(design_to_urdf(design, robot_name="robot"))
    spec = catalogue().task(task)
    return spec.load_factory()(
        design=design, urdf_path=path, options=spec.options(), simulator=engine
    )


def random_rate(env: Any, steps: int) -> float:
    """Control steps per CPU-second with random actions, resets included."""
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (steps, env.action_space.shape[0])).astype(np.float32)
    env.reset(seed=0)
    started = time.process_time()
    for action in actions:
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset()
    return steps / (time.process_time() - started)


def batch_rate(env: Any, worlds: int, steps: int, step: Any) -> float:
    """Control steps per CPU-second of ``step(batch, actions)`` (one round of all worlds)
    on a batch of ``worlds`` worlds of ``env`` given random actions, seeded and reset."""
    from adworker.batched import BatchedEnv

    batch = BatchedEnv.of(env, worlds)
    try:
        rng = np.random.default_rng(0)
        rounds = max(1, steps // worlds)
        shape = (rounds, worlds, env.action_space.shape[0])
        actions = rng.uniform(-1, 1, shape).astype(np.float32)
        batch.seed(0)
        batch.reset()
        started = time.process_time()
        for action in actions:
            step(batch, action)
        return rounds * worlds / (time.process_time() - started)
    finally:
        batch.close_copies()


def random_batch_rate(env: Any, worlds: int, steps: int) -> float:
    """Control steps per CPU-second of a batch of ``worlds`` worlds of ``env`` stepped with
    random actions, all worlds together (resets included)."""
    return batch_rate(env, worlds, steps, lambda batch, action: batch.step(action))


def physics_batch_rate(env: Any, worlds: int, steps: int) -> float:
    """Control steps per CPU-second of the engine alone on a batch of ``worlds`` worlds:
    each world's motor command and its ``frame_skip`` physics steps (MuJoCo: one
    ``mj_step`` call in C), without the state read, the task's metric and reward or the
    observation (the limit of vectorising those across worlds)."""

    def engine_alone(batch: Any, action: np.ndarray) -> None:
        for world, world_action in zip(batch.worlds, action, strict=True):
            world.robot.act(world_action)
            world.sim.step()

    return batch_rate(env, worlds, steps, engine_alone)


def ppo_rate(env: Any, steps: int, worlds: int = 1) -> float:
    """The worker's PPO (``n_envs: worlds``): env steps per CPU-second of one ``train``,
    the batch's building counted."""
    from adclient.builtin_learners import PPOOptions
    from adclient.plugins import catalogue

    learner = catalogue().learner("ppo").load_factory()(PPOOptions(n_envs=worlds))
    started = time.process_time()
    trained = learner.train(env, steps=steps, seed=0)
    seconds = time.process_time() - started
    return trained.train_steps / seconds


def ppo_batch_rate(env: Any, steps: int, worlds: int) -> float:
    """The worker's ``ppo-batch`` learner (adworker.batch_ppo, ``n_envs: worlds``, its
    other settings its defaults): env steps per CPU-second of one ``train``, the batch's
    building counted."""
    from adclient.builtin_learners import BatchPPOOptions
    from adclient.plugins import catalogue

    learner = catalogue().learner("ppo-batch").load_factory()(BatchPPOOptions(n_envs=worlds))
    started = time.process_time()
    trained = learner.train(env, steps=steps, seed=0)
    seconds = time.process_time() - started
    return trained.train_steps / seconds


def updates_per_sample(arm: str, steps: int) -> float:
    """Gradient updates per env step of an arm's training of ``steps`` steps (its
    options' ``work``)."""
    from adclient.builtin_learners import BatchPPOOptions, PPOOptions

    if arm.startswith("ppo-batch-"):
        options: Any = BatchPPOOptions(n_envs=int(arm.removeprefix("ppo-batch-")))
    else:
        options = PPOOptions()
    return options.work(steps).updates / steps


LEARN_WORLDS = (1, 16)
"""The ``--learn`` arms' ``n_envs`` of the ``ppo`` learner: today's one env and a batch;
beside them ``ppo-batch`` at its defaults (16 worlds)."""


def learned_scores(tasks: list[str], seeds: int, folder: Path) -> list[dict[str, Any]]:
    """Each task's design trained on ``ppo``'s default budget (12,288 steps) by the
    ``ppo`` learner with each of ``LEARN_WORLDS`` and by ``ppo-batch`` at its defaults,
    seeds 0 to ``seeds - 1``, on each engine: the scores (3 evaluation episodes each,
    as the worker scores a design) and each arm's CPU-seconds."""
    from adclient.builtin_learners import BatchPPOOptions, PPOOptions
    from adclient.plugins import catalogue
    from adworker.learners import evaluate_policy

    arms: list[tuple[str, str, Any]] = [
        (f"ppo n_envs {worlds}", "ppo", PPOOptions(n_envs=worlds)) for worlds in LEARN_WORLDS
    ]
    arms.append(("ppo-batch", "ppo-batch", BatchPPOOptions()))
    rows = []
    for task in tasks:
        for engine in ENGINES:
            for arm, name, options in arms:
                factory = catalogue().learner(name).load_factory()
                scores, seconds, diverged = [], 0.0, []
                for seed in range(seeds):
                    env = make_env(task, engine, folder)
                    try:
                        learner = factory(options)
                        started = time.process_time()
                        trained = learner.train(env, steps=PPOOptions.default_steps, seed=seed)
                        seconds += time.process_time() - started
                        evaluation = [(seed + 1) * 10_000 + i for i in range(3)]
                        episodes = evaluate_policy(env, trained.policy, evaluation)
                    except RuntimeError as error:  # MuJoCo's SimulationDiverged: a failed job
                        if type(error).__name__ != "SimulationDiverged":
                            raise
                        diverged.append(seed)
                        continue
                    finally:
                        env.close()
                    scores.append(float(np.mean([episode.score for episode in episodes])))
                work = options.work(PPOOptions.default_steps)
                row = {
                    "task": task,
                    "engine": engine,
                    "arm": arm,
                    "scores": scores,
                    "diverged_seeds": diverged,
                    "cpu_seconds": seconds,
                    "updates_per_sample": work.updates / PPOOptions.default_steps,
                }
                print(json.dumps(row), flush=True)
                rows.append(row)
    return rows


AGREEMENT_STUDIES = {"stand-up": "stand-up", "lift-highest": "multi-structure"}
"""The example study whose space the agreement arm draws a task's designs from."""


def random_designs(task: str, count: int, seed: int) -> list[Any]:
    """``count`` designs drawn uniformly from the task's example space."""
    import yaml

    from adclient.decode import decode, identity_representation, onehot_representation
    from adclient.schemas import StudyCreate

    path = ROOT / "examples" / f"{AGREEMENT_STUDIES[task]}.yaml"
    space = StudyCreate.model_validate(yaml.safe_load(path.read_text())).space
    several = len(space.structures) > 1
    representation = (onehot_representation if several else identity_representation)(space)
    rng = np.random.default_rng(seed)
    size = len(representation.bounds[0])
    return [decode(space, representation, rng.uniform(0, 1, size).tolist()) for _ in range(count)]


def fast_score(task: str, design: Any, engine: str, folder: Path) -> float:
    """The worker's score of ``design`` with the ``fast`` learner (its default budget,
    three evaluation episodes)."""
    from adclient.plugins import catalogue
    from adclient.urdf import design_to_urdf
    from adworker.learners import evaluate_policy

    path = folder / f"agree-{engine}.urdf"
    path.write_text(design_to_urdf(design, robot_name="robot"))
    spec = catalogue().task(task)
    env = spec.load_factory()(
        design=design, urdf_path=path, options=spec.options(), simulator=engine
    )
    try:
        learner = catalogue().learner("fast").load_factory()(None)
        trained = learner.train(env, steps=learner.default_steps, seed=0)
        episodes = evaluate_policy(env, trained.policy, [1000, 1001, 1002])
    finally:
        env.close()
    return float(np.mean([episode.score for episode in episodes]))


def agreement(task: str, count: int, folder: Path) -> dict[str, Any]:
    """Spearman's rank correlation of the two engines' fast-learner scores of ``count``
    random designs of the task."""
    from scipy.stats import spearmanr

    scores: dict[str, list[float]] = {engine: [] for engine in ENGINES}
    for design in random_designs(task, count, seed=59):
        for engine in ENGINES:
            scores[engine].append(fast_score(task, design, engine, folder))
    rho = float(spearmanr(scores["pybullet"], scores["mujoco"]).statistic)
    return {"task": task, "designs": count, "spearman": rho, "scores": scores}


LEARNERS = {"ppo": "batched", "ppo-batch": "lean"}
"""The batched arms' learners and the figures' names of each: ``batched_*`` for SB3's
PPO on the batch (``ppo``'s ``n_envs``), ``lean_*`` for ``ppo-batch``."""


def goals(
    task: str, by_engine: dict[str, dict[str, Any]], world_counts: list[int], steps: int
) -> None:
    """Issue 59's goals for ``task``, per batched learner: its best arm on each engine over
    today's baseline (SB3 PPO, one env, PyBullet; 10x for MuJoCo, 2x for PyBullet), and
    the learner's share of that arm's CPU (at most half), with the gradient updates per
    sample of that arm and of the baseline."""
    baseline = by_engine["pybullet"]["ppo"]
    for learner, figure in LEARNERS.items():
        for engine, goal in (("mujoco", 10.0), ("pybullet", 2.0)):
            row = by_engine[engine]
            best = max(world_counts, key=lambda count: row[f"{learner}-{count}"])
            arm = f"{learner}-{best}"
            speedup = row[arm] / baseline
            share = 1.0 - row[arm] / row["random-batch"]
            limit = row["physics-batch"] / baseline
            verdict = "met" if speedup >= goal else "missed"
            updates = updates_per_sample(arm, steps)
            print(
                f"{task}: {figure} {engine} PPO ({arm}) {speedup:.2f}x today's SB3 + "
                f"PyBullet (goal {goal:g}x: {verdict}); learner's share {share:.1%} "
                f"(goal <= 50%: {'met' if share <= 0.5 else 'missed'}); gradient updates "
                f"per sample {updates:.4f} (today's {updates_per_sample('ppo', steps):.4f}); "
                f"the engine alone on the batch {limit:.2f}x"
            )
            emit(
                f"{task}.{engine}.{figure}_over_baseline", speedup, higher_is_better=True, unit="x"
            )
            emit(f"{task}.{engine}.{figure}_learner_share", share, higher_is_better=False)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tasks", default="stand-up,walk-forward")
    parser.add_argument("--steps", type=int, default=3000, help="random-action control steps")
    parser.add_argument("--ppo-steps", type=int, default=4096, help="0: no PPO arm")
    parser.add_argument(
        "--agree",
        type=int,
        default=0,
        help="random designs of stand-up and lift-highest scored with the fast learner on "
        "both engines, for their rank correlation (0: none)",
    )
    parser.add_argument(
        "--worlds", default="8,16,32", help="batched arms' world counts ('': no batched arm)"
    )
    parser.add_argument("--learn", type=int, default=0, help="seeds of the learning arm (0: none)")
    parser.add_argument("--learn-tasks", default="stand-up", help="the learning arm's tasks")
    parser.add_argument("--core", type=int, default=0)
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    tasks = args.tasks.split(",")
    world_counts = [int(count) for count in args.worlds.split(",") if count]
    unknown = [task for task in tasks if task not in TASKS]
    if unknown:
        parser.error(f"unknown task(s) {', '.join(unknown)} (tasks: {', '.join(TASKS)})")
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {args.core})
    import torch

    torch.set_num_threads(1)
    rows = []
    with tempfile.TemporaryDirectory() as scratch:
        folder = Path(scratch)
        if args.ppo_steps:  # torch's and the learner's first-use set-up, left out
            warm = make_env("stand-up", "pybullet", folder)
            ppo_rate(warm, 512)
            warm.close()
        for task in tasks:
            for engine in ENGINES:
                env = make_env(task, engine, folder)
                try:
                    row = {
                        "task": task,
                        "engine": engine,
                        "joints": env.joint_count,
                        "frame_skip": env.options.frame_skip,
                        "random": random_rate(env, args.steps),
                    }
                    if world_counts:
                        row["random-batch"] = random_batch_rate(env, max(world_counts), args.steps)
                        row["random-batch-worlds"] = max(world_counts)
                        row["physics-batch"] = physics_batch_rate(
                            env, max(world_counts), args.steps
                        )
                    if args.ppo_steps:
                        row["ppo"] = ppo_rate(env, args.ppo_steps)
                        for count in world_counts:
                            row[f"ppo-{count}"] = ppo_rate(env, args.ppo_steps, count)
                        for count in world_counts:
                            row[f"ppo-batch-{count}"] = ppo_batch_rate(env, args.ppo_steps, count)
                finally:
                    env.close()
                rows.append(row)
        agreed = (
            [agreement(task, args.agree, folder) for task in AGREEMENT_STUDIES]
            if args.agree
            else []
        )
        learn_tasks = args.learn_tasks.split(",")
        learned = learned_scores(learn_tasks, args.learn, folder) if args.learn else []
    arms = ["random", *(["random-batch", "physics-batch"] if world_counts else [])]
    if args.ppo_steps:
        arms += ["ppo", *(f"ppo-{count}" for count in world_counts)]
        arms += [f"ppo-batch-{count}" for count in world_counts]
    print(f"{'task':<14} {'engine':<9} " + " ".join(f"{arm:>12}" for arm in arms))
    for row in rows:
        figures = " ".join(f"{row[arm]:>12,.0f}" for arm in arms)
        print(f"{row['task']:<14} {row['engine']:<9} {figures}")
    print(
        "(control steps per CPU-second; random-batch, physics-batch: the largest batch; "
        "ppo-N: n_envs N; "
        "ppo-batch-N: the worker's own PPO, n_envs N)"
    )
    for task in tasks:
        by_engine = {row["engine"]: row for row in rows if row["task"] == task}
        for arm in arms:
            if arm not in by_engine["pybullet"]:
                continue
            for engine, row in by_engine.items():
                emit(f"{task}.{engine}.{arm}", row[arm], higher_is_better=True, unit="steps/CPU-s")
            ratio = by_engine["mujoco"][arm] / by_engine["pybullet"][arm]
            print(f"{task}: mujoco / pybullet, {arm}: {ratio:.2f}x")
            emit(f"{task}.mujoco_over_pybullet.{arm}", ratio, higher_is_better=True, unit="x")
        if args.ppo_steps and world_counts:
            goals(task, by_engine, world_counts, args.ppo_steps)
    for agreed_task in agreed:
        name, rho = agreed_task["task"], agreed_task["spearman"]
        print(f"{name}: {agreed_task['designs']} random designs, fast learner, Spearman {rho:.3f}")
        emit(f"{name}.agreement.spearman", rho, higher_is_better=True)
    for learned_row in learned:
        task, engine, arm = learned_row["task"], learned_row["engine"], learned_row["arm"]
        scores = learned_row["scores"]
        mean = float(np.mean(scores)) if scores else float("nan")
        listed = ", ".join(f"{score:.3f}" for score in scores)
        failed = learned_row["diverged_seeds"]
        listed += f"; diverged (a failed job): seeds {failed}" if failed else ""
        print(
            f"{task}, {engine}, {arm}: mean score {mean:.3f} ({listed}); "
            f"{learned_row['cpu_seconds']:.1f} CPU-s; updates per sample "
            f"{learned_row['updates_per_sample']:.4f}"
        )
        emit(f"{task}.{engine}.learned.{arm.replace(' ', '_')}", mean, higher_is_better=True)
    if args.json is not None:
        found = {"rates": rows, "agreement": agreed, "learned": learned}
        args.json.write_text(json.dumps(found, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
