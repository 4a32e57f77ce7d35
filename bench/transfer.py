"""Controller transfer across designs (issue 27): training every design from scratch
against starting each from the nearest evaluated design's checkpoint, with and without
ASHA, through a real ``adserver`` and real ``adworker`` processes.

Each run: a fresh server on a SQLite file, one managed study (stand-up from
examples/stand-up.yaml, lift-highest from examples/multi-structure.yaml, walk-forward
from examples/walk-forward.yaml) with an SB3 learner at a budget where RL matters
(``--train-steps``, 20,000 by default), ``--trials`` designs proposed by ``qei`` with the
run's seed, and ``--workers`` adworker processes. Arms:

- ``scratch``: every design trains ``--train-steps`` from scratch (``transfer: none``);
- ``nearest``: ``transfer: nearest``; a design with an evaluated design of its tree
  starts from the nearest of the best four and trains the task's default warm budget (a
  quarter of ``--train-steps``);
- ``nearest/8``: the same with an eighth of the budget (``transfer_steps``);
- ``scratch+asha``, ``nearest+asha``: the same with the ASHA pruner of bench/pruning.py
  (rungs from a fifth of the budget, reduction factor 3).
- ``shared``: ``transfer: shared`` (issue 38): one controller for the whole study, whose
  weights fit every tree; every design after the first starts from its current version
  and trains the default warm budget (a quarter);
- ``shared+screen``: the same with screening: a median pruner that judges each design by
  the shared controller's score on it at step 0, before training (``n_startup_trials``
  4, reports only at step 0), so a design it rates below the complete designs' median
  is not trained;
- ``shared-critic``, ``shared-critic+screen``: the same with ``shared_carries: critic``
  (a design keeps the version's critic and starts its actor from the study's initial
  weights; ``shared`` keeps the default, ``all``);
- ``optuna-sb3``: what a user would write without this service: Optuna's GPSampler
  (seeded, its defaults) proposing the same space (the tree as a categorical, every spec
  a float in its range) and stable-baselines3 training every design from scratch, on
  ``--workers`` processes. The service only keeps the trials (each one enqueued, leased
  and told by this script, never proposed by the service): each design is trained and
  scored by the same code an adworker runs (``adworker.evaluate.evaluate_job``).

Measured per trial as in bench/pruning.py: worker CPU seconds (``time_cpu_s``) and the
score. Per run: the best score and the worker CPU spent until the best so far first
reached 95% of the ``scratch`` arm's median best of that task and learner (trials in
the order they finished; a run that never reached it counts as infinite). Goal (issue 27):
the same best within the seeds' spread (median at least the scratch arm's lowest) for
at least 3x less worker CPU to that 95% mark (moonshot 5x), on every task.

Results append to bench/results/transfer.jsonl (a rerun skips the runs it has); the
report and the PNG (best so far against cumulative worker CPU) come from ``--report``.
``--sitting LABEL`` keeps a set of runs made together apart from every other (CPU
seconds grow with the machine's load, so arms compare only within one sitting): its runs
are stored with the label, skipped and reported by it, and drawn in their own PNG.

Run: ``.venv/bin/python bench/transfer.py`` (all of it: days on two cores);
``--tasks stand-up --learners ppo --seeds 2 --arms scratch nearest`` for a part;
``--quick`` to check it runs (``--quick --arms shared optuna-sb3`` those arms).
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


from adclient import Client  # noqa: E402
from adclient.decode import spec_layout  # noqa: E402
from adclient.design import DesignSpace  # noqa: E402
from adclient.schemas import Job  # noqa: E402
from adclient.testing.servers import ServerProcess  # noqa: E402
from bench.pruning import (  # noqa: E402
    plot_best_against_cpu,
    pruner_of,
    run_study,
    time_to_target,
    trial_records,
)

RESULTS = ROOT / "bench" / "results" / "transfer.jsonl"
EXAMPLES = {
    "stand-up": "stand-up.yaml",
    "lift-highest": "multi-structure.yaml",
    "walk-forward": "walk-forward.yaml",
}
ARMS = [
    "scratch",
    "nearest",
    "nearest/8",
    "scratch+asha",
    "nearest+asha",
    "shared",
    "shared+screen",
    "shared-critic",
    "shared-critic+screen",
    "optuna-sb3",
]
REACHED = 0.95


def study_body(task: str, learner: str, arm: str, seed: int, args: argparse.Namespace) -> dict:
    body = yaml.safe_load((ROOT / "examples" / EXAMPLES[task]).read_text())
    body["name"] = f"transfer-{task}-{learner}-{arm}-{seed}"
    body["proposer"] = {"name": "qei", "n_initial": 4, "seed": seed}
    body["task"] = {
        "name": task,
        "learner": learner,
        "train_steps": args.train_steps,
        "seed": seed,
        "transfer": transfer_of(arm),
        "transfer_steps": warm_steps(arm, args.train_steps),
    }
    if arm.startswith("shared"):
        body["task"]["shared_carries"] = "critic" if arm.startswith("shared-critic") else "all"
    body["max_trials"] = args.trials
    body["pruner"] = pruner_of("asha" if arm.endswith("+asha") else "none", args.train_steps)
    if arm.endswith("+screen"):
        screen = {"n_startup_trials": 4, "n_warmup_steps": 0}
        body["pruner"] = {"name": "median", "options": screen, "report_every": args.train_steps}
    return body


def transfer_of(arm: str) -> str:
    for kind in ("nearest", "shared"):
        if arm.startswith(kind):
            return kind
    return "none"


def warm_steps(arm: str, train_steps: int) -> int | None:
    """A warm start's budget: the task's default (a quarter) or, for ``nearest/8``, an
    eighth of the from-scratch budget."""
    return train_steps // 8 if arm.endswith("/8") else None


def run_one(task: str, learner: str, arm: str, seed: int, args: argparse.Namespace) -> dict:
    """One study end to end; its trials as records."""
    body = study_body(task, learner, arm, seed, args)
    if arm == "optuna-sb3":
        info, trials, wall = run_optuna_sb3(body, seed=seed, workers=args.workers)
    else:
        info, trials, wall = run_study(body, workers=args.workers, timeout=args.timeout)
    return {
        "task": task,
        "learner": learner,
        "arm": arm,
        "seed": seed,
        "train_steps": args.train_steps,
        "transfer_steps": warm_steps(arm, args.train_steps),
        "max_trials": args.trials,
        "sitting": args.sitting,
        "trials": trials,
        "best": info.best_value,
        "n_pruned": info.n_pruned,
        "n_failed": info.n_failed,
        "n_transferred": sum(
            1 for t in trials if t["transfer_from"] is not None or (t.get("shared_from") or 0) > 0
        ),
        "wall_s": wall,
        "worker_cpu_s": sum(t["cpu_seconds"] or 0.0 for t in trials),
    }


def run_optuna_sb3(body: dict[str, Any], *, seed: int, workers: int) -> tuple[Any, list, float]:
    """The ``optuna-sb3`` arm: GPSampler asks, ``workers`` processes train and score each
    design from scratch (``evaluate_job``, as adworker does), GPSampler is told; a
    server on a SQLite file keeps the trials so they are recorded as every arm's are."""
    import multiprocessing
    from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait

    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    layout = spec_layout(DesignSpace.model_validate(body["space"]))
    task = body["task"]["name"]
    with tempfile.TemporaryDirectory(prefix="bench-optuna-") as folder:
        work = Path(folder)
        # leases outlive any training here: this script sends no heartbeats
        env = {"AD_LEASE_SECONDS": str(7 * 24 * 3600)}
        server = ServerProcess(
            database_url=f"sqlite:///{work / 'studies.db'}", workdir=work, env=env
        ).start()
        try:
            spawn = multiprocessing.get_context("spawn")
            with Client(server.url) as client, ProcessPoolExecutor(workers, spawn) as pool:
                study = client.create_study(body)
                sampler = optuna.samplers.GPSampler(seed=seed)
                proposer = optuna.create_study(direction="maximize", sampler=sampler)
                running: dict[Future, tuple[optuna.trial.Trial, int]] = {}
                asked, started = 0, time.monotonic()
                while asked < body["max_trials"] or running:
                    while asked < body["max_trials"] and len(running) < workers:
                        trial = proposer.ask()
                        params: dict[str, Any] = {
                            "structure_index": trial.suggest_categorical(
                                "structure_index", list(range(len(layout.structures)))
                            )
                        }
                        for k, name in enumerate(layout.names):
                            params[name] = trial.suggest_float(
                                name,
                                float(layout.low[k]),
                                float(layout.high[k]),
                                log=bool(layout.log[k]),
                            )
                        client.add_trials(study.id, [{"params": params}])
                        job = client.lease("optuna-sb3", tasks=[task])
                        assert job is not None and job.study_id == study.id
                        folder_of_job = str(work / f"trial-{job.trial_id}")
                        future = pool.submit(evaluate_design, job.model_dump_json(), folder_of_job)
                        running[future] = (trial, job.trial_id)
                        asked += 1
                    done, _ = wait(running, return_when=FIRST_COMPLETED)
                    for future in done:
                        trial, trial_id = running.pop(future)
                        value, metrics = future.result()
                        client.tell(trial_id, value, metrics=metrics, worker_id="optuna-sb3")
                        proposer.tell(trial, value)
                wall = time.monotonic() - started
                info = client.study_info(study.id)
                trials = trial_records(client.trials(study.id))
        finally:
            server.stop()
    return info, trials, wall


def evaluate_design(job_json: str, workdir: str) -> tuple[float, dict[str, float]]:
    """Train and score one design from scratch in this process, as adworker would; its
    value, and its metrics with the process's CPU seconds (``time_cpu_s``)."""
    from adworker.evaluate import evaluate_job

    started = time.process_time()
    evaluation = evaluate_job(Job.model_validate_json(job_json), Path(workdir), render=False)
    return evaluation.value, {**evaluation.metrics, "time_cpu_s": time.process_time() - started}


def cpu_to_reach(run: dict[str, Any], target: float) -> float:
    """Worker CPU spent until the best so far first reached ``target`` (inf: never)."""
    for spent, best in time_to_target(run):
        if best >= target:
            return spent
    return math.inf


def best_within(run: dict[str, Any], cpu: float) -> float | None:
    """The best score a run had reached within ``cpu`` worker CPU seconds (None: none)."""
    reached = [best for spent, best in time_to_target(run) if spent <= cpu]
    return reached[-1] if reached else None


def scratch_at_same_cpu(group: list[dict[str, Any]], scratch: list[dict[str, Any]]) -> str:
    """The median over seeds of the scratch run's best by the CPU this arm's run of the
    same seed spent in all: what the same worker time bought without transfer."""
    by_seed = {run["seed"]: run for run in scratch}
    bests = [
        best_within(by_seed[run["seed"]], run["worker_cpu_s"])
        for run in group
        if run["seed"] in by_seed
    ]
    found = [best for best in bests if best is not None]
    if not found:
        return "-"
    return f"{statistics.median(found):.4f}"


def report(runs: list[dict[str, Any]]) -> str:
    """Per task, learner and arm: the best (median and range over seeds), the total
    worker CPU, the CPU to reach 95% of the scratch arm's median best (a seed that never
    reached it counts as infinite, so a median over seeds most of which never did is
    "never"), and both as ratios to the scratch arm. Goal: median best at least the
    scratch arm's lowest, and at least 3x less CPU to the 95% mark. Beside the best, the
    scratch arm's best within the same worker CPU (seed by seed)."""
    lines = [
        "| task | learner | arm | seeds | best (median, min..max) | scratch's best at the "
        "same CPU (median) | worker CPU s (median) "
        f"| total CPU vs scratch | CPU to {REACHED:.0%} of scratch's median best (median; "
        "seeds that reached it) | vs scratch | designs transferred (median) | goal |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    groups: dict[tuple[str, str, str], list[dict[str, Any]]] = {}
    for run in runs:
        groups.setdefault((run["task"], run["learner"], run["arm"]), []).append(run)
    for (task, learner, arm), group in sorted(groups.items()):
        scratch = groups.get((task, learner, "scratch"))
        bests = [r["best"] for r in group if r["best"] is not None]
        cpu = statistics.median(r["worker_cpu_s"] for r in group)
        total, to_target, ratio, goal, same_cpu = "-", "-", "-", "-", "-"
        if scratch:
            target = REACHED * statistics.median(r["best"] for r in scratch)
            reach = [cpu_to_reach(r, target) for r in group]
            spent = statistics.median(reach)
            reached = sum(math.isfinite(s) for s in reach)
            shown = f"{spent:.0f}" if math.isfinite(spent) else "never"
            to_target = f"{shown} ({reached}/{len(reach)})"
            if arm != "scratch":
                same_cpu = scratch_at_same_cpu(group, scratch)
                total = f"{statistics.median(r['worker_cpu_s'] for r in scratch) / cpu:.2f}x less"
                base = statistics.median(cpu_to_reach(r, target) for r in scratch)
                less = base / spent if math.isfinite(spent) else 0.0
                ratio = f"{less:.2f}x less" if math.isfinite(spent) else "never"
                floor = min(r["best"] for r in scratch)
                same = bool(bests) and statistics.median(bests) >= floor
                goal = "met" if same and less >= 3 else "missed"
        best = f"{statistics.median(bests):.4f} ({min(bests):.4f}..{max(bests):.4f})"
        moved = statistics.median(r["n_transferred"] for r in group)
        lines.append(
            f"| {task} | {learner} | {arm} | {len(group)} | {best} | {same_cpu} | {cpu:.0f} "
            f"| {total} "
            f"| {to_target} | {ratio} | {moved:g} | {goal} |"
        )
    return "\n".join(lines)


COLOURS = {
    "scratch": "black",
    "nearest": "tab:red",
    "scratch+asha": "tab:gray",
    "nearest/8": "tab:purple",
    "nearest+asha": "tab:orange",
    "shared": "tab:blue",
    "shared+screen": "tab:cyan",
    "shared-critic": "tab:olive",
    "shared-critic+screen": "tab:pink",
    "optuna-sb3": "tab:green",
}


def plot(runs: list[dict[str, Any]], path: Path) -> None:
    def panel(run: dict[str, Any]) -> str:
        return f"{run['task']}, {run['learner']}"

    plot_best_against_cpu(runs, path, panel=panel, arm="arm", colours=COLOURS)


def _key(run: dict[str, Any]) -> tuple[Any, ...]:
    fields = ("task", "learner", "arm", "seed", "train_steps", "transfer_steps", "max_trials")
    return (*(run[field] for field in fields), run.get("sitting"))


def figure(args: argparse.Namespace) -> Path:
    """The PNG of this command's budgets and trial count (the issue's setting: transfer.png)."""
    results = ROOT / "bench" / "results"
    sitting = f"-{args.sitting}" if args.sitting else ""
    if (args.train_steps, args.trials) == (20_000, 16):
        return results / f"transfer{sitting}.png"
    return results / f"transfer-{args.train_steps}steps-{args.trials}trials{sitting}.png"


def load(args: argparse.Namespace) -> list[dict[str, Any]]:
    """The stored runs at this command's budgets, trial count and sitting (none: the
    runs stored without one)."""
    if not RESULTS.exists():
        return []
    runs = [json.loads(line) for line in RESULTS.read_text().splitlines() if line.strip()]
    setting = (args.train_steps, args.trials, args.sitting)
    return [r for r in runs if (r["train_steps"], r["max_trials"], r.get("sitting")) == setting]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=list(EXAMPLES), choices=list(EXAMPLES))
    parser.add_argument("--learners", nargs="+", default=["ppo", "sac"])
    parser.add_argument("--arms", nargs="+", default=ARMS, choices=ARMS)
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--trials", type=int, default=16)
    parser.add_argument("--train-steps", type=int, default=20_000)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--timeout", type=float, default=12 * 3600)
    parser.add_argument(
        "--sitting", default=None, help="label of runs made together, kept and reported apart"
    )
    parser.add_argument("--quick", action="store_true", help="a smoke run, not recorded")
    parser.add_argument("--report", action="store_true", help="report the stored runs only")
    args = parser.parse_args()
    if args.quick:
        args.tasks, args.learners, args.seeds, args.trials = ["stand-up"], ["ppo"], 1, 4
        args.train_steps = 512
        args.arms = ["scratch", "nearest"] if args.arms == ARMS else args.arms
    if not args.report:
        done = {_key(run) for run in load(args)}
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            for task in args.tasks:
                for learner in args.learners:
                    for arm in args.arms:
                        key = (task, learner, arm, seed, args.train_steps)
                        key += (warm_steps(arm, args.train_steps), args.trials, args.sitting)
                        if key in done and not args.quick:
                            continue
                        run = run_one(task, learner, arm, seed, args)
                        print(
                            f"{task} {learner} {arm} seed {seed}: best {run['best']}, "
                            f"{run['worker_cpu_s']:.0f} worker CPU s, "
                            f"{run['n_transferred']} transferred, {run['n_pruned']} pruned",
                            flush=True,
                        )
                        if not args.quick:
                            RESULTS.parent.mkdir(parents=True, exist_ok=True)
                            with RESULTS.open("a") as out:
                                out.write(json.dumps(run) + "\n")
    runs = load(args) if not args.quick else []
    if runs:
        print(report(runs))
        plot(runs, figure(args))
        print(f"figure: {figure(args)}")


if __name__ == "__main__":
    main()
