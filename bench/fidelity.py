"""Multi-fidelity design studies (issue 61): worker CPU to a good design, four ways, on
the robot tasks with PPO, through a real ``adserver`` and real ``adworker`` processes.

Each run (a task, an arm and a seed) has a fresh server (a SQLite file) and one adworker
per study (started once the study is ready, stopped when it is done), so a job has the
worker to itself; a sitting runs every arm of a task and seed in turn (several sittings
may run side by side, one process each, ``--first-seed``):

- ``full``: today's study: ``qei`` (4 initial points), every design trained to the full
  budget (``--full-steps``), ``--full-trials`` designs.
- ``asha``: the same with the existing ASHA pruner (rungs at ``--min-steps`` and twice
  that, reduction factor 2, a report every half of ``--min-steps``), ``--asha-trials``.
- ``short-top-k``: "train every candidate briefly, keep the top K" (Egele et al. 2023):
  ``--short-trials`` Sobol designs at ``--min-steps``, then the ``--top-k`` best enqueued
  in a second study and trained to the full budget.
- ``fidelity``: ``task.fidelity`` (min ``--min-steps``, max the full budget, 3 levels,
  ``fixed_cost`` ``--fixed-cost``): the default proposer's multi-fidelity choice (BOCA,
  adservice/proposers/fidelity.py), ``--fidelity-trials``.

Measured per trial: the worker's CPU seconds for the job (``time_cpu_s``) and, for a
trial trained to the full budget, its score. A run's curve is the best full-budget score
so far against the worker CPU spent so far, trials in the order they finished (a short
run's score, or a pruned trial's, is never a best). The goal (issue 61): the CPU the
``fidelity`` arm takes to reach the ``full`` arm's median best at least 3x less than
``full`` takes, and its best ahead of ``asha``'s and ``short-top-k``'s at equal CPU.

Results append to bench/results/fidelity.jsonl (a rerun skips the sittings it has);
``--report`` prints the table. Run:
``nice -n 5 .venv/bin/python bench/fidelity.py --tasks stand-up lift-highest walk-forward
--seeds 3``; ``--quick`` checks that it runs (tiny budgets, one seed, not recorded).
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import tempfile
from pathlib import Path
from typing import Any

import yaml

from adclient import Client
from adclient.schemas import Trial
from adclient.testing.figures import emit
from adclient.testing.servers import ServerProcess
from adclient.testing.workers import WorkerProcess, stop_workers

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "bench" / "results"
"""Where runs append: fidelity-TASK.jsonl, one file a task (sittings of several tasks may
run side by side); the report reads them all."""
EXAMPLES = {
    "stand-up": "stand-up.yaml",
    "lift-highest": "multi-structure.yaml",
    "walk-forward": "walk-forward.yaml",
}
ARMS = ("full", "asha", "short-top-k", "fidelity")
TIMEOUT = 3600.0


def base_body(task: str, arm: str, seed: int, args: argparse.Namespace) -> dict[str, Any]:
    """The task's example study with PPO at the full budget, ``qei`` seeded by ``seed``."""
    body = yaml.safe_load((ROOT / "examples" / EXAMPLES[task]).read_text())
    body["name"] = f"fidelity-{task}-{arm}-{seed}"
    body["proposer"] = {"name": "qei", "n_initial": 4, "seed": seed}
    body["task"] = {
        "name": task,
        "learner": "ppo",
        "train_steps": args.full_steps,
        "seed": seed,
        "options": {"learner_kwargs": {"n_steps": args.n_steps, "batch_size": 128}},
    }
    body.pop("pruner", None)
    return body


def arm_bodies(task: str, arm: str, seed: int, args: argparse.Namespace) -> dict[str, Any]:
    body = base_body(task, arm, seed, args)
    if arm == "full":
        body["max_trials"] = args.full_trials
    elif arm == "asha":
        body["max_trials"] = args.asha_trials
        body["pruner"] = {
            "name": "asha",
            "options": {"min_resource": args.min_steps, "reduction_factor": 2},
            "report_every": max(1, args.min_steps // 2),
        }
    elif arm == "short-top-k":
        body["max_trials"] = args.short_trials
        body["proposer"] = {"name": "sobol", "seed": seed}
        body["task"]["train_steps"] = args.min_steps
    elif arm == "fidelity":
        body["max_trials"] = args.fidelity_trials
        del body["task"]["train_steps"]
        body["task"]["fidelity"] = {
            "min": args.min_steps,
            "max": args.full_steps,
            "levels": 3,
            "fixed_cost": args.fixed_cost,
        }
    else:
        raise ValueError(f"unknown arm {arm!r}")
    return body


def records(trials: list[Trial], *, full_steps: int, phase: int = 0) -> list[dict[str, Any]]:
    """A study's trials as the results file keeps them; ``full``: trained to the full
    budget (its score may be a best)."""
    return [
        {
            "number": t.number,
            "phase": phase,
            "state": t.state.value,
            "value": t.value,
            "cpu_s": t.metrics.get("time_cpu_s") or 0.0,
            "train_steps": t.metrics.get("train_steps"),
            "fidelity": t.info.get("fidelity"),
            "full": t.state.value == "complete"
            and (t.metrics.get("train_steps") or 0) >= full_steps,
            "finished_at": t.finished_at.isoformat() if t.finished_at else None,
            "params": t.params,
        }
        for t in trials
    ]


def finish(client: Client, server: ServerProcess, work: Path, study: Any, name: str) -> None:
    """One adworker until ``study`` is done."""
    worker = WorkerProcess(server, work, name, "--no-render", "--poll", "0.3")
    try:
        study.wait(poll=0.5, timeout=TIMEOUT)
    finally:
        stop_workers([worker])


def run_arm(task: str, arm: str, seed: int, args: argparse.Namespace) -> dict[str, Any]:
    with tempfile.TemporaryDirectory(prefix="bench-fidelity-") as folder:
        work = Path(folder)
        server = ServerProcess(database_url=f"sqlite:///{work / 'studies.db'}", workdir=work)
        server.start()
        try:
            # a loaded machine: a design study's creation (its fusion QP) can take minutes
            with Client(server.url, timeout=600.0) as client:
                body = arm_bodies(task, arm, seed, args)
                study = client.create_study(body)
                finish(client, server, work, study, "w0")
                trials = records(study.trials, full_steps=args.full_steps)
                if arm == "short-top-k":
                    trials += top_k(client, server, work, body, trials, args)
        finally:
            server.stop()
    order = sorted(trials, key=lambda t: (t["phase"], t["finished_at"] or ""))
    return {"task": task, "arm": arm, "seed": seed, "settings": settings(args), "trials": order}


def top_k(
    client: Client,
    server: ServerProcess,
    work: Path,
    body: dict[str, Any],
    short: list[dict[str, Any]],
    args: argparse.Namespace,
) -> list[dict[str, Any]]:
    """The ``--top-k`` best short runs' designs trained to the full budget, enqueued in
    a second study (created, filled, then served by a worker: nothing else proposed)."""
    done = [t for t in short if t["state"] == "complete" and t["value"] is not None]
    best = sorted(done, key=lambda t: -t["value"])[: args.top_k]
    second = {**body, "name": body["name"] + "-top", "max_trials": len(best)}
    second["task"] = {**body["task"], "train_steps": args.full_steps}
    study = client.create_study(second)
    for trial in best:
        study.enqueue_trial(trial["params"])
    finish(client, server, work, study, "w1")
    return records(study.trials, full_steps=args.full_steps, phase=1)


SETTINGS = (
    "full_steps",
    "min_steps",
    "n_steps",
    "fixed_cost",
    "full_trials",
    "asha_trials",
    "short_trials",
    "top_k",
    "fidelity_trials",
)
"""What a run depends on besides its task, arm and seed."""


def settings(args: argparse.Namespace) -> dict[str, Any]:
    return {key: getattr(args, key) for key in SETTINGS}


def curve(run: dict[str, Any]) -> list[tuple[float, float]]:
    """(worker CPU spent, best full-budget score so far) after each finished trial."""
    spent, best, points = 0.0, -math.inf, []
    for trial in run["trials"]:
        spent += trial["cpu_s"]
        if trial["full"] and trial["value"] is not None:
            best = max(best, trial["value"])
        points.append((spent, best))
    return points


def cpu_to(run: dict[str, Any], target: float) -> float:
    """The worker CPU at which the run's best full-budget score first reaches ``target``
    (inf: never)."""
    return next((spent for spent, best in curve(run) if best >= target - 1e-12), math.inf)


def best_at(run: dict[str, Any], cpu: float) -> float:
    """The run's best full-budget score once ``cpu`` worker seconds are spent (-inf: none)."""
    best = -math.inf
    for spent, value in curve(run):
        if spent > cpu + 1e-9:
            break
        best = value
    return best


def median(values: list[float]) -> float:
    return statistics.median(values) if values else math.nan


def report(runs: list[dict[str, Any]]) -> str:
    lines = [
        "| task | arm | seeds | best (median, min..max) | worker CPU s (median) | "
        "CPU to full's median best (median) | vs full | best at equal CPU (median) | "
        "full-budget trials (median) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for task in EXAMPLES:
        by_arm = {arm: [r for r in runs if r["task"] == task and r["arm"] == arm] for arm in ARMS}
        if not by_arm["full"]:
            continue
        ends = {arm: [curve(r)[-1] for r in rs] for arm, rs in by_arm.items() if rs}
        target = median([best for _, best in ends["full"]])
        equal = min(median([spent for spent, _ in points]) for points in ends.values())
        full_cpu = median([cpu_to(r, target) for r in by_arm["full"]])
        for arm, arm_runs in by_arm.items():
            if not arm_runs:
                continue
            bests = [best for _, best in ends[arm]]
            to_target = median([cpu_to(r, target) for r in arm_runs])
            ratio = full_cpu / to_target if math.isfinite(to_target) else 0.0
            saving = f"{ratio:.2f}x less" if ratio else "never reached"
            at_equal = median([best_at(r, equal) for r in arm_runs])
            n_full = median([sum(t["full"] for t in r["trials"]) for r in arm_runs])
            lines.append(
                f"| {task} | {arm} | {len(arm_runs)} | {median(bests):.3f} "
                f"({min(bests):.3f}..{max(bests):.3f}) | "
                f"{median([spent for spent, _ in ends[arm]]):.0f} | "
                f"{to_target:.0f} | {saving} | {at_equal:.3f} (at {equal:.0f} s) | "
                f"{n_full:g} |"
            )
            if arm == "fidelity":
                emit(
                    f"{task} fidelity CPU saving to full's median best",
                    ratio,
                    higher_is_better=True,
                    unit="x",
                )
    return "\n".join(lines)


def load(folder: Path) -> list[dict[str, Any]]:
    return [
        json.loads(line)
        for path in sorted(folder.glob("fidelity-*.jsonl"))
        for line in path.read_text().splitlines()
        if line.strip()
    ]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tasks", nargs="+", default=list(EXAMPLES), choices=list(EXAMPLES))
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--arms", nargs="+", default=list(ARMS), choices=ARMS)
    parser.add_argument("--full-steps", type=int, default=2048)
    parser.add_argument("--min-steps", type=int, default=512)
    parser.add_argument("--n-steps", type=int, default=256, help="PPO's rollout length")
    parser.add_argument("--fixed-cost", type=int, default=512)
    parser.add_argument("--full-trials", type=int, default=8)
    parser.add_argument("--asha-trials", type=int, default=12)
    parser.add_argument("--short-trials", type=int, default=14)
    parser.add_argument("--top-k", type=int, default=2)
    parser.add_argument("--fidelity-trials", type=int, default=14)
    parser.add_argument("--results", type=Path, default=RESULTS)
    parser.add_argument("--report", action="store_true", help="only print the table")
    parser.add_argument("--quick", action="store_true", help="tiny budgets, one seed")
    args = parser.parse_args()
    if args.quick:
        args.full_steps, args.min_steps, args.n_steps = 256, 64, 64
        args.full_trials, args.asha_trials, args.short_trials = 3, 3, 3
        args.top_k, args.fidelity_trials, args.seeds = 1, 4, 1
        args.results = Path(tempfile.mkdtemp())
    runs = load(args.results)
    if not args.report:
        have = {(r["task"], r["arm"], r["seed"], json.dumps(r["settings"])) for r in runs}
        args.results.mkdir(parents=True, exist_ok=True)
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            for task in args.tasks:
                for arm in args.arms:
                    if (task, arm, seed, json.dumps(settings(args))) in have:
                        continue
                    run = run_arm(task, arm, seed, args)
                    with (args.results / f"fidelity-{task}.jsonl").open("a") as out:
                        out.write(json.dumps(run) + "\n")
                    runs.append(run)
                    spent, best = curve(run)[-1]
                    print(
                        f"{task} {arm} seed {seed}: best {best:.3f}, worker CPU {spent:.1f} s",
                        flush=True,
                    )
    mine = [r for r in runs if r["settings"] == settings(args)]
    print(report(mine))


if __name__ == "__main__":
    main()
