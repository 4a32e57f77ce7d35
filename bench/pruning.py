"""Early stopping over the RL budget (issue 15): no pruner vs median vs ASHA, through a
real ``adserver`` and real ``adworker`` processes.

Each run: a fresh server on a SQLite file, one managed study (stand-up from
examples/stand-up.yaml, lift-highest from examples/multi-structure.yaml) with an SB3
learner at a budget where early stopping matters (``--train-steps``, 20,000 by default),
``--trials`` trials, proposer ``qei`` with the run's seed, and ``--workers`` adworker
processes (one job each at a time). What is measured per trial: its worker CPU seconds
(``time_cpu_s``: the worker process's CPU time for the job, interim evaluations and
checkpoints included; a paused trial's resumed job adds its earlier seconds; CPU rather
than wall time, so a busy shared machine slows no arm more than another), its wall
seconds (``time_total_s``) and, for complete trials, the score. From those: the best
score, total worker seconds, and the time-to-target curve (best complete score so far
against worker CPU seconds spent, trials in the order they finished).

Variants: ``none``, ``median``, ``asha`` (a trial stopped at a rung is pruned) and
``asha-promotion`` (ASHA with ``promotion: true``: it is paused with its SB3 checkpoint
and resumes from it if promoted later; docs/pruning.md).

Goal (issue 15): the same best score within the seeds' spread with at least 2x less
total worker time (moonshot 4x).

Results append to bench/results/pruning.jsonl (a rerun skips the runs it has); the
report (medians over seeds, ratios to no pruner) and the PNG are written by
``--report``. ``--quick`` is a smoke run (fast learner, a few trials, one seed).

Run: ``.venv/bin/python bench/pruning.py`` (all of it: hours on two cores);
``--tasks stand-up --seeds 1 --variants none asha`` for a part; ``--quick`` to check it
runs.
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import yaml

from adclient import Client
from adclient.schemas import Trial
from adclient.testing.servers import ServerProcess
from adclient.testing.workers import WorkerProcess, stop_workers

ROOT = Path(__file__).resolve().parents[1]

RESULTS = ROOT / "bench" / "results" / "pruning.jsonl"
FIGURE = ROOT / "bench" / "results" / "pruning.png"
EXAMPLES = {"stand-up": "stand-up.yaml", "lift-highest": "multi-structure.yaml"}


def pruner_of(variant: str, train_steps: int) -> dict[str, Any]:
    """The study's pruner for a variant; reports every tenth of the budget."""
    every = max(1, train_steps // 10)
    if variant == "none":
        return {"name": "none"}
    if variant == "median":
        options = {"n_startup_trials": 5, "n_warmup_steps": 3 * every}
        return {"name": "median", "options": options, "report_every": every}
    if variant == "asha":
        options = {"min_resource": 2 * every, "reduction_factor": 3}
        return {"name": "asha", "options": options, "report_every": every}
    if variant == "asha-promotion":
        asha = pruner_of("asha", train_steps)
        return {**asha, "options": {**asha["options"], "promotion": True}}
    if variant == "asha-left-out":
        return {**pruner_of("asha", train_steps), "pruned_as": "left_out"}
    raise ValueError(f"unknown variant {variant!r}")


def study_body(task: str, variant: str, seed: int, args: argparse.Namespace) -> dict[str, Any]:
    body = yaml.safe_load((ROOT / "examples" / EXAMPLES[task]).read_text())
    body["name"] = f"pruning-{task}-{variant}-{seed}"
    body["proposer"] = {"name": "qei", "n_initial": 4, "seed": seed}
    body["task"] = {
        "name": task,
        "learner": args.learner,
        "train_steps": args.train_steps,
        "seed": seed,
    }
    body["max_trials"] = args.trials
    body["pruner"] = pruner_of(variant, args.train_steps)
    return body


def trial_records(trials: list[Trial]) -> list[dict[str, Any]]:
    """A study's trials as the records a results file keeps."""
    return [
        {
            "number": t.number,
            "state": t.state.value,
            "value": t.value,
            "method": t.info.get("method"),
            "seconds": t.metrics.get("time_total_s"),
            "cpu_seconds": t.metrics.get("time_cpu_s"),
            "resumed_from_step": t.metrics.get("resumed_from_step"),
            "train_steps": t.metrics.get("train_steps"),
            "transfer_from": t.info.get("transfer_from"),
            "transfer_distance": t.metrics.get("transfer_distance"),
            "shared_from": t.metrics.get("shared_from"),
            "finished_at": t.finished_at.isoformat() if t.finished_at else None,
        }
        for t in trials
    ]


def run_study(body: dict[str, Any], *, workers: int, timeout: float) -> tuple[Any, list, float]:
    """A managed study end to end on a fresh server (a SQLite file) with ``workers``
    adworker processes: (its final info, its trials as records, wall seconds)."""
    with tempfile.TemporaryDirectory(prefix="bench-study-") as folder:
        work = Path(folder)
        server = ServerProcess(database_url=f"sqlite:///{work / 'studies.db'}", workdir=work)
        server.start()
        processes: list[WorkerProcess] = []
        try:
            with Client(server.url) as client:
                study = client.create_study(body)
                started = time.monotonic()
                processes = [
                    WorkerProcess(server, work, f"w{i}", "--no-render", "--poll", "0.5")
                    for i in range(workers)
                ]
                info = study.wait(poll=1.0, timeout=timeout)
                wall = time.monotonic() - started
                trials = trial_records(study.trials)
        finally:
            stop_workers(processes)
            server.stop()
    return info, trials, wall


def run_one(task: str, variant: str, seed: int, args: argparse.Namespace) -> dict[str, Any]:
    """One study end to end; its trials as records."""
    body = study_body(task, variant, seed, args)
    info, trials, wall = run_study(body, workers=args.workers, timeout=args.timeout)
    return {
        "task": task,
        "variant": variant,
        "seed": seed,
        "learner": args.learner,
        "train_steps": args.train_steps,
        "max_trials": args.trials,
        "trials": trials,
        "best": info.best_value,
        "n_pruned": info.n_pruned,
        "n_failed": info.n_failed,
        "wall_s": wall,
        "worker_s": sum(t["seconds"] or 0.0 for t in trials),
        "worker_cpu_s": sum(t["cpu_seconds"] or 0.0 for t in trials),
        "n_resumed": sum(1 for t in trials if t["resumed_from_step"]),
    }


def time_to_target(run: dict[str, Any]) -> list[tuple[float, float]]:
    """(worker CPU seconds spent, best complete score so far) after each finished trial."""
    done = sorted((t for t in run["trials"] if t["finished_at"]), key=lambda t: t["finished_at"])
    spent, best, points = 0.0, float("-inf"), []
    for trial in done:
        spent += trial["cpu_seconds"] or 0.0
        if trial["state"] == "complete" and trial["value"] is not None:
            best = max(best, trial["value"])
        if best > float("-inf"):
            points.append((spent, best))
    return points


def report(runs: list[dict[str, Any]]) -> str:
    """Medians over seeds per task and variant, ratios of worker CPU time to no pruner,
    and the goal: a median best within the seeds' spread of no pruner's bests (at least
    its lowest) with at least 2x less worker CPU time."""
    lines = [
        "| task | variant | seeds | best (median, min..max) | worker CPU s (median) | "
        "wall s (median) | CPU vs none | pruned | resumed | goal |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for run in runs:
        groups.setdefault((run["task"], run["variant"]), []).append(run)
    for (task, variant), group in sorted(groups.items()):
        bests = [r["best"] for r in group if r["best"] is not None]
        cpu = statistics.median(r["worker_cpu_s"] for r in group)
        wall = statistics.median(r["worker_s"] for r in group)
        baseline = groups.get((task, "none"))
        ratio, goal = "-", "-"
        if baseline and variant != "none" and cpu > 0:
            less = statistics.median(r["worker_cpu_s"] for r in baseline) / cpu
            ratio = f"{less:.2f}x less"
            floor = min(r["best"] for r in baseline if r["best"] is not None)
            same = bool(bests) and statistics.median(bests) >= floor
            goal = "met" if same and less >= 2 else "missed"
        best = (
            f"{statistics.median(bests):.4f} ({min(bests):.4f}..{max(bests):.4f})" if bests else "-"
        )
        pruned = statistics.median(r["n_pruned"] for r in group)
        resumed = statistics.median(r.get("n_resumed", 0) for r in group)
        lines.append(
            f"| {task} | {variant} | {len(group)} | {best} | {cpu:.0f} | {wall:.0f} | {ratio} "
            f"| {pruned:g} | {resumed:g} | {goal} |"
        )
    return "\n".join(lines)


COLOURS = {"none": "black", "median": "tab:blue", "asha": "tab:orange", "asha-promotion": "tab:red"}


def plot(runs: list[dict[str, Any]], path: Path) -> None:
    plot_best_against_cpu(runs, path, panel=lambda run: run["task"], arm="variant", colours=COLOURS)


def plot_best_against_cpu(
    runs: list[dict[str, Any]],
    path: Path,
    *,
    panel: Callable[[dict[str, Any]], str],
    arm: str,
    colours: dict[str, str],
) -> None:
    """One panel per ``panel(run)``: each run's best complete score so far against the
    worker CPU seconds spent, coloured by its ``run[arm]``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    titles = sorted({panel(run) for run in runs})
    figure, axes = plt.subplots(1, len(titles), figsize=(6 * len(titles), 4), squeeze=False)
    for axis, title in zip(axes[0], titles, strict=True):
        for run in (r for r in runs if panel(r) == title):
            points = time_to_target(run)
            if points:
                xs, ys = zip(*points, strict=True)
                colour = colours.get(run[arm], "tab:green")
                axis.step(xs, ys, where="post", color=colour, alpha=0.6, label=run[arm])
        handles, labels = axis.get_legend_handles_labels()
        unique = dict(zip(labels, handles, strict=True))
        axis.legend(unique.values(), unique.keys())
        axis.set(title=title, xlabel="worker CPU seconds", ylabel="best complete score")
    figure.tight_layout()
    figure.savefig(path, dpi=100)


def _key(run: dict[str, Any]) -> tuple[Any, ...]:
    fields = ("task", "variant", "seed", "learner", "train_steps", "max_trials")
    return tuple(run[field] for field in fields)


def load(args: argparse.Namespace) -> list[dict[str, Any]]:
    """The stored runs at this command's learner, budget and trial count."""
    if not RESULTS.exists():
        return []
    runs = [json.loads(line) for line in RESULTS.read_text().splitlines() if line.strip()]
    setting = (args.learner, args.train_steps, args.trials)
    return [r for r in runs if (r["learner"], r["train_steps"], r["max_trials"]) == setting]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=list(EXAMPLES), choices=list(EXAMPLES))
    parser.add_argument(
        "--variants", nargs="+", default=["none", "median", "asha", "asha-promotion"]
    )
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--trials", type=int, default=20)
    parser.add_argument("--train-steps", type=int, default=20_000)
    parser.add_argument("--learner", default="ppo")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--timeout", type=float, default=6 * 3600)
    parser.add_argument("--quick", action="store_true", help="a smoke run, not recorded")
    parser.add_argument("--report", action="store_true", help="report the stored runs only")
    args = parser.parse_args()
    if args.quick:
        args.tasks, args.seeds, args.trials = ["stand-up"], 1, 4
        args.train_steps, args.learner = 640, "fast"
    if not args.report:
        done = {_key(run) for run in load(args)}
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            for task in args.tasks:
                for variant in args.variants:
                    key = (task, variant, seed, args.learner, args.train_steps, args.trials)
                    if key in done and not args.quick:
                        continue
                    run = run_one(task, variant, seed, args)
                    print(
                        f"{task} {variant} seed {seed}: best {run['best']}, "
                        f"{run['worker_cpu_s']:.0f} worker CPU s, {run['worker_s']:.0f} wall s, "
                        f"{run['n_pruned']} pruned, {run['n_resumed']} resumed",
                        flush=True,
                    )
                    if not args.quick:
                        RESULTS.parent.mkdir(parents=True, exist_ok=True)
                        with RESULTS.open("a") as out:
                            out.write(json.dumps(run) + "\n")
    runs = load(args) if not args.quick else []
    if runs:
        print(report(runs))
        plot(runs, FIGURE)
        print(f"figure: {FIGURE}")


if __name__ == "__main__":
    main()
