"""Does one shared controller transfer across designs (issue 38)? The modular policy of
:mod:`adworker.modular` on a chain of designs, each starting from the previous design's
shared weights, against training every design from scratch.

Per task, a fixed list of designs (stand-up: four arches and near-arches of the
example's space, lengths and axes varied; lift-highest: four trees of
examples/multi-structure.yaml, three to five links). Per seed and design, PPO at
bench/transfer.py's budget (``--train-steps``, 20,000), three arms:

- ``mlp``: the plain learner, an MLP from scratch, the full budget (``transfer: none``);
- ``modular``: the modular policy from the study's initial weights, the full budget;
- ``chain``: the modular policy from the previous design's update (the first design
  from the initial weights), a quarter of the budget: what one worker running the
  designs one after the other would see under ``transfer: shared``;
- ``quarter``: the modular policy from the initial weights, a quarter of the budget:
  ``chain``'s designs without what the earlier designs taught, so ``chain`` against it
  is what the transfer itself is worth;
- ``chain-explore``: as ``chain``, with the policy's log standard deviation put back
  to the initial weights' at each design: the exploration a fresh policy has, on the
  weights the earlier designs taught;
- ``chain-critic``: as ``chain``, but only the critic carries (its head of the tree
  network, its pooling and value layer); the actor starts from the initial weights;
- ``chain-half``: as ``chain``, each design from halfway between the initial weights
  and the previous design's update;
- ``mlp-chain``: the MLP, each design warm-started from the previous design's final
  checkpoint for a quarter of the budget (the first from scratch, a quarter too), as
  ``transfer: nearest`` starts a design: ``chain``'s protocol with the plain learner,
  so the two compare the policies' fine-tuning alone (designs of one tree only: the MLP
  does not fit another tree's, and says so in ``problem``).

Each design is scored as a worker scores it (the task's default evaluation episodes
with the worker's seeds, deterministic policy) and its CPU seconds (training and
evaluation, one thread) are measured in this process. Results append to
bench/results/shared_policy.jsonl (a rerun skips what it has; ``--sitting LABEL`` keeps
runs made together apart: a change of the code's arithmetic moves every score a little,
and CPU seconds move with the machine's load); ``--report`` prints the
table of bench/RESULTS.md ("A shared controller (issue 38)").

Run: ``.venv/bin/python bench/shared_policy.py --tasks stand-up --seeds 0 1 2
--designs 3`` (about 30 CPU minutes: a design costs about 45 CPU s with the MLP, 120
with the modular policy, 35 in the chain); one process per seed to use more cores;
``--report`` for the table.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from adworker.designs import HALF_PI, tree_design  # noqa: E402
from adworker.shared_weights import actor_part  # noqa: E402

RESULTS = ROOT / "bench" / "results" / "shared_policy.jsonl"
ARMS = [
    "mlp",
    "modular",
    "chain",
    "quarter",
    "chain-explore",
    "chain-critic",
    "chain-half",
    "mlp-chain",
]
CHAINED = ("chain", "chain-explore", "chain-critic", "chain-half")
"""The arms whose designs start from the previous design's update."""
LOG_STD = "log_std"
"""The modular policy's array of its action noise's log standard deviation."""
EVAL_EPISODES = 5
CHAIN = [("a", "b"), ("b", "c")]
DESIGNS = {
    "stand-up": [
        ("arch 0.40", CHAIN, {"b": (HALF_PI, HALF_PI), "c": (HALF_PI, HALF_PI)}, 0.40),
        ("tilted 0.30", CHAIN, {"b": (1.3, 1.8), "c": (1.8, 1.4)}, 0.30),
        ("arch 0.55", CHAIN, {"b": (HALF_PI, HALF_PI), "c": (HALF_PI, HALF_PI)}, 0.55),
        ("skew 0.45", CHAIN, {"b": (1.2, 1.3), "c": (1.9, 1.9)}, 0.45),
    ],
    "lift-highest": [
        ("chain of 3", CHAIN, {"b": (HALF_PI, HALF_PI), "c": (HALF_PI, HALF_PI)}, 0.4),
        (
            "star of 4",
            [("a", "b"), ("a", "c"), ("a", "d")],
            {"b": (HALF_PI, HALF_PI), "c": (HALF_PI, 0.5), "d": (HALF_PI, 2.6)},
            0.4,
        ),
        (
            "fork on b",
            [("a", "b"), ("b", "c"), ("b", "d")],
            {"b": (HALF_PI, HALF_PI), "c": (HALF_PI, 0.5), "d": (HALF_PI, 2.6)},
            0.4,
        ),
        (
            "chain of 4",
            [("a", "b"), ("b", "c"), ("c", "d")],
            {"b": (HALF_PI, HALF_PI), "c": (HALF_PI, HALF_PI), "d": (HALF_PI, 0.0)},
            0.4,
        ),
    ],
}


def make_env(task: str, index: int, folder: Path) -> Any:
    from adclient.plugins import catalogue
    from adclient.urdf import design_to_urdf

    _, edges, angles, length = DESIGNS[task][index]
    design = tree_design(edges, angles, length=length)
    path = folder / f"{task}-{index}.urdf"
    path.write_text(design_to_urdf(design, robot_name="robot"))
    spec = catalogue().task(task)
    return spec.load_factory()(
        design=design, urdf_path=path, options=spec.options(), render_mode=None
    )


def score(env: Any, policy: Any, seed: int) -> float:
    """The worker's score: the mean over its evaluation episodes and seeds."""
    from adworker.evaluate import EVAL_SEED_STRIDE
    from adworker.learners import evaluate_policy

    seeds = [(seed + 1) * EVAL_SEED_STRIDE + i for i in range(EVAL_EPISODES)]
    return statistics.fmean(result.score for result in evaluate_policy(env, policy, seeds))


def run_seed(task: str, seed: int, args: argparse.Namespace, done: set[tuple]) -> None:
    """Every arm of one task and seed, each design in order (the chain carries its
    weights from one design to the next)."""
    import torch

    from adworker.learners import PPOLearner
    from adworker.starts import SCRATCH, Shared, Warm

    torch.set_num_threads(1)
    weights: dict[str, Any] = dict.fromkeys(CHAINED)
    checkpoint: bytes | None = None  # mlp-chain's last design's
    initial: Any = None
    with tempfile.TemporaryDirectory(prefix="bench-shared-") as folder:
        for index, (name, *_) in enumerate(DESIGNS[task][: args.designs]):
            for arm in args.arms:
                if arm in CHAINED:
                    start: Any = Shared(weights[arm], steps=args.train_steps // 4, seed=seed)
                elif arm == "quarter":
                    start = Shared(None, steps=args.train_steps // 4, seed=seed)
                elif arm == "modular":
                    start = Shared(None, steps=args.train_steps, seed=seed)
                elif arm == "mlp-chain" and checkpoint is not None:
                    start = Warm(checkpoint, steps=args.train_steps // 4)
                else:
                    start = SCRATCH
                steps = args.train_steps
                if arm == "mlp-chain" and checkpoint is None:
                    steps = args.train_steps // 4
                key = (task, arm, seed, index, args.train_steps)
                if key in done and arm not in CHAINED and arm != "mlp-chain":
                    continue
                env = make_env(task, index, Path(folder))
                learner = PPOLearner()
                began = time.process_time()
                result = learner.train(
                    env,
                    steps=steps,
                    seed=seed * 100 + index,
                    start=start,
                    keep_checkpoint=arm == "mlp-chain",
                )
                value = score(env, result.policy, seed)
                cpu = time.process_time() - began
                env.close()
                if arm in CHAINED:
                    assert result.shared is not None  # PPO with a Shared start returns one
                    initial = initial if start.weights is not None else result.shared_start
                    weights[arm] = carried(arm, result.shared, initial)
                    if key in done:
                        continue
                if arm == "mlp-chain":
                    checkpoint = result.checkpoint
                    if key in done:
                        continue
                record = {
                    "task": task,
                    "arm": arm,
                    "seed": seed,
                    "design": index,
                    "name": name,
                    "train_steps": args.train_steps,
                    "steps": result.train_steps,
                    "score": value,
                    "cpu_s": cpu,
                    "problem": learner.warm_problem,
                    "sitting": args.sitting,
                }
                print(json.dumps(record), flush=True)
                RESULTS.parent.mkdir(parents=True, exist_ok=True)
                with RESULTS.open("a") as out:
                    out.write(json.dumps(record) + "\n")


def carried(arm: str, update: dict[str, Any], initial: dict[str, Any]) -> dict[str, Any]:
    """What a chained arm's next design starts from, given the last design's update."""
    if arm == "chain-explore":
        return {**update, LOG_STD: initial[LOG_STD]}
    if arm == "chain-half":
        return {name: (update[name] + initial[name]) / 2 for name in update}
    if arm == "chain-critic":  # as shared_carries: critic (adworker.modular.fresh_actor)
        start = {name: value.copy() for name, value in update.items()}
        for name, value in start.items():
            actor = actor_part(name, value)
            if actor is not None:
                actor[...] = actor_part(name, initial[name])
        return start
    return update


def load(sitting: str | None) -> list[dict[str, Any]]:
    """The stored records of ``sitting`` (None: those stored without one)."""
    if not RESULTS.exists():
        return []
    records = [json.loads(line) for line in RESULTS.read_text().splitlines() if line.strip()]
    return [r for r in records if r.get("sitting") == sitting]


def report(records: list[dict[str, Any]], train_steps: int) -> str:
    """Per task and design: each arm's median score (min..max over seeds) and median CPU
    seconds; then per task the arms' totals over the designs."""
    rows = [r for r in records if r["train_steps"] == train_steps]
    lines = [
        "| task | design | "
        + " | ".join(f"{arm} score (median, min..max)" for arm in ARMS)
        + " | "
        + " | ".join(f"{arm} CPU s" for arm in ARMS)
        + " | seeds |",
        "|---|---|" + "---|" * (2 * len(ARMS) + 1),
    ]
    for task, designs in DESIGNS.items():
        for index, (name, *_) in enumerate(designs):
            cells, cpus, seeds = [], [], set()
            for arm in ARMS:
                found = [
                    r for r in rows if (r["task"], r["arm"], r["design"]) == (task, arm, index)
                ]
                seeds |= {r["seed"] for r in found}
                if not found:
                    cells.append("-")
                    cpus.append("-")
                    continue
                values = [r["score"] for r in found]
                cells.append(
                    f"{statistics.median(values):.3f} ({min(values):.3f}..{max(values):.3f})"
                )
                cpus.append(f"{statistics.median(r['cpu_s'] for r in found):.0f}")
            if seeds:
                lines.append(
                    f"| {task} | {index}: {name} | "
                    + " | ".join(cells + cpus)
                    + f" | {len(seeds)} |"
                )
    return "\n".join([*lines, "", totals(rows)])


def totals(rows: list[dict[str, Any]]) -> str:
    """Per task and arm, over the designs every arm that ran ran with the most seeds: the
    mean score (median over the seeds) and the CPU seconds summed over them (median)."""
    lines = [
        "| task | arm | designs | seeds | mean score over the designs (median over seeds) "
        "| CPU s over the designs (median) | CPU / mlp's |",
        "|---|---|---|---|---|---|---|",
    ]
    for task in DESIGNS:
        ran = [r for r in rows if r["task"] == task]
        seeds_of = {
            (design, arm): {r["seed"] for r in ran if (r["design"], r["arm"]) == (design, arm)}
            for design in {r["design"] for r in ran}
            for arm in {r["arm"] for r in ran}
        }
        most = max((len(seeds) for seeds in seeds_of.values()), default=0)
        designs = {design for design, _ in seeds_of} - {
            design for (design, _), seeds in seeds_of.items() if len(seeds) < most
        }
        summed: dict[str, tuple[int, float, float]] = {}
        for arm in ARMS:
            by_seed: dict[int, list[dict[str, Any]]] = {}
            for r in ran:
                if r["arm"] == arm and r["design"] in designs:
                    by_seed.setdefault(r["seed"], []).append(r)
            whole = [found for found in by_seed.values() if len(found) == len(designs)]
            if designs and whole:
                summed[arm] = (
                    len(whole),
                    statistics.median(statistics.fmean(r["score"] for r in f) for f in whole),
                    statistics.median(sum(r["cpu_s"] for r in f) for f in whole),
                )
        for arm, (seeds, value, cpu) in summed.items():
            ratio = f"{cpu / summed['mlp'][2]:.2f}" if "mlp" in summed else "-"
            lines.append(
                f"| {task} | {arm} | {len(designs)} | {seeds} | {value:.3f} | {cpu:.0f} | {ratio} |"
            )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=["stand-up"], choices=list(DESIGNS))
    parser.add_argument("--arms", nargs="+", default=ARMS, choices=ARMS)
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--train-steps", type=int, default=20_000)
    parser.add_argument("--designs", type=int, default=4, help="the first N of each task's")
    parser.add_argument(
        "--sitting",
        default=None,
        help="label of runs made together (the code and the machine's load of one day), "
        "stored, skipped and reported apart from the others",
    )
    parser.add_argument("--report", action="store_true", help="report the stored runs only")
    args = parser.parse_args()
    if not args.report:
        done = {
            (r["task"], r["arm"], r["seed"], r["design"], r["train_steps"])
            for r in load(args.sitting)
        }
        for task in args.tasks:
            for seed in args.seeds:
                run_seed(task, seed, args, done)
    print(report(load(args.sitting), args.train_steps))


if __name__ == "__main__":
    main()
