"""The ``mpc`` learner against PPO (issue 59): how a training-free evaluator's ranking of
designs agrees with the ``ppo`` learner's, and what each costs, in one run on one core.

    python bench/mpc.py [--designs 16] [--tasks stand-up,lift-highest] [--ppo-steps N]
        [--mpc-options '{"samples": 32}'] [--cem] [--core 0] [--json FILE]

The designs are bench/engines.py's ``--agree`` arm's (its ``random_designs``: uniform
draws of examples/stand-up.yaml's space and of examples/multi-structure.yaml's, seed 59),
each built on MuJoCo as the worker builds it and scored as the worker scores any learner
(the task's three evaluation episodes of a task seed 0, ``evaluate_policy``) with ``mpc``
(its defaults, or ``--mpc-options``), ``ppo`` at its default budget (12,288 steps, unless
``--ppo-steps``) and ``fast`` (and, with ``--cem``, ``mpc-cem``: mpc's options with
``method: cem``). Per task: Spearman's rank correlation of mpc's scores with
ppo's and with fast's (and fast's with ppo's), and the CPU seconds per design of each
learner (``time.process_time``: its training and its evaluation episodes, one thread,
the process pinned to ``--core``; torch's first set-up in the process left out by one
short PPO training before any is measured).

Prints a table and one ``BENCH`` line per figure (``bench/compare.py``); ``--json``
writes every score.
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
from bench.engines import AGREEMENT_STUDIES, random_designs  # noqa: E402

LEARNERS = ("mpc", "ppo", "fast")
EVALUATION_SEEDS = [10_000, 10_001, 10_002]
"""A task seed 0's three evaluation episodes, as the worker seeds them
(``adworker.evaluate.evaluation_seeds``)."""


def scored(
    task: str, design: Any, learner: str, folder: Path, options: dict[str, Any], steps: int | None
) -> tuple[float, float]:
    """``design``'s score on MuJoCo with ``learner`` (its options ``options``, ``steps``
    or its default budget) as the worker scores it, and the CPU seconds it took."""
    from adclient.plugins import catalogue
    from adclient.urdf import design_to_urdf
    from adworker.learners import evaluate_policy

    path = folder / "robot.urdf"
    path.write_text(design_to_urdf(design, robot_name="robot"))
    spec = catalogue().task(task)
    declared = catalogue().learner(learner)
    model = None if declared.options is None else declared.options.model_validate(options)
    started = time.process_time()
    env = spec.load_factory()(
        design=design, urdf_path=path, options=spec.options(), simulator="mujoco"
    )
    try:
        chosen = declared.load_factory()(model)
        budget = chosen.default_steps if steps is None else steps
        trained = chosen.train(env, steps=budget, seed=0)
        episodes = evaluate_policy(env, trained.policy, EVALUATION_SEEDS)
    finally:
        env.close()
    return float(np.mean([e.score for e in episodes])), time.process_time() - started


def compare(
    task: str,
    count: int,
    folder: Path,
    arms: dict[str, tuple[str, dict[str, Any]]],
    ppo_steps: int | None,
) -> dict[str, Any]:
    """Every arm's scores of the task's ``count`` designs, their CPU seconds, and each
    arm's Spearman rank correlation with ``ppo``'s and ``fast``'s."""
    from scipy.stats import spearmanr

    scores: dict[str, list[float]] = {name: [] for name in arms}
    seconds: dict[str, list[float]] = {name: [] for name in arms}
    for k, design in enumerate(random_designs(task, count, seed=59)):
        for name, (learner, options) in arms.items():
            steps = ppo_steps if learner == "ppo" else None
            score, cpu = scored(task, design, learner, folder, options, steps)
            scores[name].append(score)
            seconds[name].append(cpu)
        row = ", ".join(f"{n} {scores[n][-1]:.3f} ({seconds[n][-1]:.1f} s)" for n in arms)
        print(f"  {task} design {k}: {row}", flush=True)
    pairs = [(a, b) for a in arms for b in ("ppo", "fast") if a not in ("ppo", b)]
    return {
        "task": task,
        "designs": count,
        "spearman": {
            f"{a}~{b}": float(spearmanr(scores[a], scores[b]).statistic) for a, b in pairs
        },
        "cpu_s_per_design": {name: float(np.mean(seconds[name])) for name in arms},
        "scores": scores,
        "seconds": seconds,
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--designs", type=int, default=16)
    parser.add_argument("--tasks", default=",".join(AGREEMENT_STUDIES))
    parser.add_argument("--ppo-steps", type=int, default=None)
    parser.add_argument("--mpc-options", default="{}", help="mpc's learner_kwargs, JSON")
    parser.add_argument(
        "--cem", action="store_true", help="an arm mpc-cem besides: mpc's options, method cem"
    )
    parser.add_argument("--core", type=int, default=0)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {args.core})
    import torch

    torch.set_num_threads(1)
    mpc_options = json.loads(args.mpc_options)
    arms = {name: (name, mpc_options if name == "mpc" else {}) for name in LEARNERS}
    if args.cem:
        arms["mpc-cem"] = ("mpc", mpc_options | {"method": "cem"})
    tasks = [t for t in args.tasks.split(",") if t]
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        # torch's set-up, once a worker: not a design's cost
        scored(tasks[0], random_designs(tasks[0], 1, seed=0)[0], "ppo", folder, {}, 64)
        results = [compare(t, args.designs, folder, arms, args.ppo_steps) for t in tasks]
    print()
    for r in results:
        rho, cpu = r["spearman"], r["cpu_s_per_design"]
        print(f"{r['task']}, {r['designs']} designs:")
        print("  Spearman " + ", ".join(f"{pair} {value:.3f}" for pair, value in rho.items()))
        print("  CPU s/design " + ", ".join(f"{name} {value:.2f}" for name, value in cpu.items()))
        means = {name: float(np.mean(r["scores"][name])) for name in arms}
        print("  mean score " + ", ".join(f"{name} {value:.3f}" for name, value in means.items()))
        for pair, value in rho.items():
            emit(f"{r['task']}.spearman.{pair}", value, higher_is_better=True)
        for name, value in cpu.items():
            emit(f"{r['task']}.cpu_s_per_design.{name}", value, higher_is_better=False)
    if args.json is not None:
        args.json.write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
