"""Best-known score per task and learner, the yardstick of bench/paper.py's targets.

    .venv/bin/python bench/best_known.py            # resumable; ~15 min on 2 idle cores
    .venv/bin/python bench/best_known.py --quick    # smoke run, separate files

For each task of the paper bench (the design space of its example study, unchanged)
it runs, through the same evaluation code the workers run (``adworker.evaluate``
in-process, ``--jobs`` processes, one BLAS thread each):

1. dense: a scrambled Sobol set of designs (256 for stand-up and diagonal-gesture;
   64 per candidate structure, 384 in all, for lift-highest, so every structure is
   sampled alike), the fast learner, task seed 0;
2. local: the 4 best distinct designs each perturbed 24 times (Gaussian, sigma 0.08
   of each spec's range, same structure), fast learner, seed 0;
3. re-evaluation: the 8 best distinct designs of 1+2 with task seeds 1, 2, 3; a
   design's fast score is its mean over seeds 0-3 (one lucky seed does not set the bar);
4. retraining: the 4 best designs by that mean trained with the default RL learner
   (``ddpg``, its default budget) with seeds 0 and 1; a design's RL score is the mean.

``best_known[task][learner]`` is the best such mean; bench/paper.py's target for a
study with that learner is ``TARGET_FRACTION`` (95%) of it. The fast learner and DDPG
score one design differently (DDPG in 3,000 steps rarely finds the pose the constant-
target search holds), so each learner is judged against its own best.

Every evaluation is appended to ``bench/results/best_known_evals.jsonl`` as it ends;
a rerun skips those already there. The summary goes to ``bench/results/best_known.json``.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.paperlib import (
    BEST_KNOWN,
    RESULTS,
    TARGET_FRACTION,
    TASKS,
    append_jsonl,
    interrupt_on_sigterm,
    read_jsonl,
    study_body,
    use_snapshot,
)
from bench.paperlib import QUICK as QUICK_DIR

RL_LEARNER = "ddpg"


@dataclass(frozen=True)
class Plan:
    dense: dict[str, int]
    """Sobol designs per structure, by task."""
    local_parents: int
    local_children: int
    local_sigma: float
    reeval_top: int
    reeval_seeds: tuple[int, ...]
    rl_top: int
    rl_seeds: tuple[int, ...]
    rl_train_steps: int | None


FULL = Plan(
    dense={"stand-up": 256, "diagonal-gesture": 256, "lift-highest": 64},
    local_parents=4,
    local_children=24,
    local_sigma=0.08,
    reeval_top=8,
    reeval_seeds=(1, 2, 3),
    rl_top=4,
    rl_seeds=(0, 1),
    rl_train_steps=None,
)
QUICK = Plan(
    dense={"stand-up": 8, "diagonal-gesture": 8, "lift-highest": 2},
    local_parents=1,
    local_children=2,
    local_sigma=0.08,
    reeval_top=2,
    reeval_seeds=(1,),
    rl_top=1,
    rl_seeds=(0,),
    rl_train_steps=300,
)


# -- one evaluation (runs in a pool process) -------------------------------------------

_CACHE: dict[str, Any] = {}


def _space_and_representation(task: str) -> tuple[Any, Any, Any]:
    """The task's space (one-hot encoded when it has several structures: every design
    is then reachable exactly) and its representation, built once per process."""
    if task not in _CACHE:
        from adclient.decode import identity_representation, onehot_representation
        from adclient.design import DesignSpace
        from adclient.schemas import TaskConfig

        body = study_body(task)
        space = DesignSpace.model_validate(body["space"])
        if len(space.tree_structures()) > 1:
            space = space.model_copy(update={"encoding": "onehot"})
            representation = onehot_representation(space)
        else:
            representation = identity_representation(space)
        _CACHE[task] = (space, representation, TaskConfig.model_validate(body["task"]))
    return _CACHE[task]


def evaluate_design(
    task: str, structure: int, x: list[float], learner: str, seed: int, train_steps: int | None
) -> dict[str, Any]:
    """Score one design (structure index + normalised spec vector) like a worker would."""
    from adclient.decode import design_params
    from adclient.schemas import Job
    from adworker.evaluate import evaluate_job

    space, representation, task_config = _space_and_representation(task)
    count = len(space.tree_structures())
    vector = list(x) if count == 1 else [float(k == structure) for k in range(count)] + list(x)
    config = task_config.model_copy(
        update={"learner": learner, "seed": seed, "train_steps": train_steps}
    )
    job = Job(
        trial_id=1,
        study_id=1,
        number=0,
        attempt=1,
        vector=vector,
        params={},
        task=config,
        space=space,
        representation=representation,
        lease_expires_at=datetime(2100, 1, 1, tzinfo=UTC),
    )
    started, cpu = time.perf_counter(), time.process_time()
    with tempfile.TemporaryDirectory(prefix="best-known-") as workdir:
        evaluation = evaluate_job(job, Path(workdir), render=False)
    return {
        "value": evaluation.value,
        "wall_s": time.perf_counter() - started,
        "cpu_s": time.process_time() - cpu,
        "params": design_params(evaluation.design),
    }


def _init_worker() -> None:
    os.environ["OMP_NUM_THREADS"] = "1"
    os.environ["MKL_NUM_THREADS"] = "1"


# -- designs ---------------------------------------------------------------------------


def dense_designs(task: str, per_structure: int) -> list[tuple[int, list[float]]]:
    """Scrambled Sobol spec vectors per structure over the slots it uses (others PAD)."""
    import warnings

    from scipy.stats import qmc

    from adclient.decode import PAD, spec_layout

    space, _, _ = _space_and_representation(task)
    layout = spec_layout(space)
    designs = []
    for index, structure in enumerate(layout.structures):
        used = layout.used_slots(structure)
        sampler = qmc.Sobol(int(used.sum()), scramble=True, rng=np.random.default_rng([7, index]))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)
            points = sampler.random(per_structure)
        for point in points:
            x = np.full(layout.size, PAD)
            x[used] = point
            designs.append((index, x.tolist()))
    return designs


def perturbed(
    task: str, structure: int, x: list[float], count: int, sigma: float, seed: int
) -> list[tuple[int, list[float]]]:
    from adclient.decode import spec_layout

    space, _, _ = _space_and_representation(task)
    layout = spec_layout(space)
    used = layout.used_slots(layout.structures[structure])
    rng = np.random.default_rng([11, seed])
    out = []
    for _ in range(count):
        child = np.asarray(x, dtype=np.float64).copy()
        child[used] = np.clip(child[used] + rng.normal(0.0, sigma, int(used.sum())), 0.0, 1.0)
        out.append((structure, child.tolist()))
    return out


# -- the run ---------------------------------------------------------------------------


class Runner:
    """Evaluates keyed designs in a process pool, appending each result as it ends."""

    def __init__(self, path: Path, jobs: int, progress: Any) -> None:
        self.path = path
        self.done = {record["key"]: record for record in read_jsonl(path)}
        self.jobs = jobs
        self.progress = progress
        self.pool: ProcessPoolExecutor | None = None

    def __enter__(self) -> Runner:
        import multiprocessing

        self.pool = ProcessPoolExecutor(
            self.jobs, mp_context=multiprocessing.get_context("spawn"), initializer=_init_worker
        )
        return self

    def __exit__(self, *exc: object) -> None:
        assert self.pool is not None
        self.pool.shutdown(wait=True, cancel_futures=True)

    def run(self, label: str, items: list[dict[str, Any]]) -> list[dict[str, Any]]:
        """Each item: key, task, design_id, structure, x, learner, seed, train_steps, stage."""
        assert self.pool is not None
        todo = [item for item in items if item["key"] not in self.done]
        task_id = self.progress.add_task(label, total=len(items), completed=len(items) - len(todo))
        pending: dict[Future[dict[str, Any]], dict[str, Any]] = {}
        queue = list(todo)
        while queue or pending:
            while queue and len(pending) < 2 * self.jobs:
                item = queue.pop(0)
                future = self.pool.submit(
                    evaluate_design,
                    item["task"],
                    item["structure"],
                    item["x"],
                    item["learner"],
                    item["seed"],
                    item["train_steps"],
                )
                pending[future] = item
            finished, _ = wait(pending, return_when=FIRST_COMPLETED)
            for future in finished:
                item = pending.pop(future)
                record = {**item, **future.result()}
                append_jsonl(self.path, record)
                self.done[item["key"]] = record
                self.progress.advance(task_id)
        return [self.done[item["key"]] for item in items]


def _item(
    task: str,
    stage: str,
    design_id: str,
    structure: int,
    x: list[float],
    learner: str,
    seed: int,
    train_steps: int | None = None,
) -> dict[str, Any]:
    return {
        "key": f"{task}|{stage}|{design_id}|{learner}|{seed}",
        "task": task,
        "stage": stage,
        "design_id": design_id,
        "structure": structure,
        "x": x,
        "learner": learner,
        "seed": seed,
        "train_steps": train_steps,
    }


def _best_distinct(records: list[dict[str, Any]], count: int) -> list[dict[str, Any]]:
    """The best ``count`` records by value, one per design."""
    seen: set[str] = set()
    out = []
    for record in sorted(records, key=lambda r: -r["value"]):
        if record["design_id"] in seen:
            continue
        seen.add(record["design_id"])
        out.append(record)
        if len(out) == count:
            break
    return out


def run_task(task: str, plan: Plan, runner: Runner) -> dict[str, Any]:
    dense = [
        _item(task, "dense", f"dense:{i}", s, x, "fast", 0)
        for i, (s, x) in enumerate(dense_designs(task, plan.dense[task]))
    ]
    dense_results = runner.run(f"{task}: dense", dense)
    parents = _best_distinct(dense_results, plan.local_parents)
    local = []
    for p, parent in enumerate(parents):
        children = perturbed(
            task, parent["structure"], parent["x"], plan.local_children, plan.local_sigma, p
        )
        for c, (s, x) in enumerate(children):
            local.append(_item(task, "local", f"local:{p}:{c}", s, x, "fast", 0))
    local_results = runner.run(f"{task}: local", local)
    top = _best_distinct(dense_results + local_results, plan.reeval_top)
    reeval = [
        _item(task, "reeval", r["design_id"], r["structure"], r["x"], "fast", seed)
        for r in top
        for seed in plan.reeval_seeds
    ]
    reeval_results = runner.run(f"{task}: re-evaluate", reeval)
    fast_scores = _means(top + reeval_results)
    ranked = sorted(top, key=lambda r: -fast_scores[r["design_id"]]["mean"])
    rl = [
        _item(
            task,
            "rl",
            r["design_id"],
            r["structure"],
            r["x"],
            RL_LEARNER,
            seed,
            plan.rl_train_steps,
        )
        for r in ranked[: plan.rl_top]
        for seed in plan.rl_seeds
    ]
    rl_results = runner.run(f"{task}: {RL_LEARNER}", rl)
    rl_scores = _means(rl_results)
    all_fast = dense_results + local_results
    summary: dict[str, Any] = {
        "evaluations": {
            "dense": len(dense_results),
            "local": len(local_results),
            "reeval": len(reeval_results),
            RL_LEARNER: len(rl_results),
        },
        "dense_best_single": max(r["value"] for r in dense_results),
        "local_best_single": max((r["value"] for r in local_results), default=None),
        "dense_median": float(np.median([r["value"] for r in dense_results])),
        "fast_cpu_s": float(sum(r["cpu_s"] for r in all_fast + reeval_results)),
        f"{RL_LEARNER}_cpu_s": float(sum(r["cpu_s"] for r in rl_results)),
    }
    by_id = {r["design_id"]: r for r in all_fast}
    for learner, scores in (("fast", fast_scores), (RL_LEARNER, rl_scores)):
        best_id = max(scores, key=lambda k: scores[k]["mean"])
        summary[learner] = {
            "score": scores[best_id]["mean"],
            "target": TARGET_FRACTION * scores[best_id]["mean"],
            "design_id": best_id,
            "seed_scores": scores[best_id]["values"],
            "params": by_id[best_id]["params"],
            "candidates": {k: round(v["mean"], 4) for k, v in scores.items()},
        }
    return summary


def _means(records: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    grouped: dict[str, list[float]] = {}
    for record in records:
        grouped.setdefault(record["design_id"], []).append(record["value"])
    return {k: {"mean": float(np.mean(v)), "values": v} for k, v in grouped.items()}


def main(argv: list[str] | None = None) -> int:
    interrupt_on_sigterm()
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--quick", action="store_true", help="smoke run: tiny plan, files under var/paper/quick"
    )
    parser.add_argument("--jobs", type=int, default=2, help="evaluation processes (default 2)")
    parser.add_argument("--tasks", default=",".join(TASKS), help="comma-separated task names")
    args = parser.parse_args(argv)
    code, _ = use_snapshot(quick=args.quick)
    from rich.console import Console
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
    )

    plan = QUICK if args.quick else FULL
    out_dir = QUICK_DIR if args.quick else RESULTS
    evals_path = out_dir / "best_known_evals.jsonl"
    summary_path = out_dir / "best_known.json" if args.quick else BEST_KNOWN
    tasks = [t for t in args.tasks.split(",") if t]
    unknown = [t for t in tasks if t not in TASKS]
    if unknown:
        parser.error(f"unknown task(s) {unknown}; known: {list(TASKS)}")
    console = Console()
    started = time.perf_counter()
    summaries: dict[str, Any] = {}
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn())
    with (
        Progress(*columns, TimeElapsedColumn(), console=console) as progress,
        Runner(evals_path, args.jobs, progress) as runner,
    ):
        for task in tasks:
            summaries[task] = run_task(task, plan, runner)
    previous = {}
    if summary_path.exists():
        import json

        previous = json.loads(summary_path.read_text()).get("tasks", {})
    document = {
        "what": (
            "best-known score per task and learner (see bench/best_known.py): dense Sobol "
            "search + local perturbation with the fast learner, the top designs re-evaluated "
            f"over 4 task seeds, the top 4 retrained with {RL_LEARNER} over 2 seeds; "
            f"target = {TARGET_FRACTION} x best-known"
        ),
        "quick": args.quick,
        "code": code,
        "target_fraction": TARGET_FRACTION,
        "tasks": {**previous, **summaries},
    }
    import json

    summary_path.parent.mkdir(parents=True, exist_ok=True)
    summary_path.write_text(json.dumps(document, indent=1) + "\n")
    for task, summary in summaries.items():
        console.print(
            f"{task}: fast {summary['fast']['score']:.4f} (target "
            f"{summary['fast']['target']:.4f}), {RL_LEARNER} {summary[RL_LEARNER]['score']:.4f} "
            f"(target {summary[RL_LEARNER]['target']:.4f}); dense median "
            f"{summary['dense_median']:.4f}, dense best {summary['dense_best_single']:.4f}"
        )
    console.print(f"wrote {summary_path} in {time.perf_counter() - started:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
