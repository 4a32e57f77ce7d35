"""The preprint's Table 1, measured: evaluations to a good robot design, by method.

    .venv/bin/python bench/best_known.py               # once: targets (best_known.json)
    .venv/bin/python bench/paper.py                    # fast learner, 10 seeds (resumable)
    .venv/bin/python bench/paper.py --learner ddpg     # the preprint's RL learner, 3 seeds
    .venv/bin/python bench/paper.py --report           # tables, plots, images from the results
    .venv/bin/python bench/paper.py --quick            # smoke run only: 1 seed, 5 evaluations

Every study is a real one: one ``adserver`` on a SQLite file and one ``adworker
--concurrency 2`` (two evaluation processes), both started here from the pinned code
(``bench/results/code_ref``, see ``paperlib.snapshot``), the study body being the
task's example study (``examples/*.yaml``) with its proposer, proposer seed, task seed,
learner and budget replaced. Studies run one at a time, so each has both workers.

Grid: tasks stand-up, diagonal-gesture, lift-highest (the multi-structure example:
six candidate trees); methods qei (the preprint's method: qei on the fused
encoding, the default until issue 12), nelder-mead, tpe, random, plus ``qei-onehot``
on lift-highest (the same qei study on the plain encoding: ``encoding: onehot``,
structure one-hot + specs) and ``qei-mixed``, today's default, run from a later
commit with ``--code`` (``bench/paper.py --methods qei-mixed --code HEAD``); seeds 0..N-1
(the proposer's seed and the task's seed both = the seed). Budgets: 15 evaluations
for qei (the preprint's setting and the goal's), 30 for the baselines so their
evaluations-to-target can be counted past 15 (success within 15 is reported for
every method).

Each finished study is appended to ``bench/results/paper-<learner>.jsonl`` (its
trials' scores, timings, best design); a rerun skips the (task, method, learner,
seed) cells already there. ``--report`` (also run at the end of every run) writes the
"Paper Table 1 (issue 7)" section of bench/RESULTS.md, docs/paper.md, the best-so-far
plots and the best designs' pictures under docs/paper/.
"""

from __future__ import annotations

import argparse
import os
import re
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.paperlib import (
    BASELINE_BUDGET,
    DEFAULT_SEEDS,
    MODEL_BUDGET,
    QUICK,
    REPO,
    RESULTS,
    RL_SEEDS,
    TASKS,
    append_jsonl,
    interrupt_on_sigterm,
    read_jsonl,
    study_body,
    use_snapshot,
)

METHODS: dict[str, tuple[str, str]] = {
    "qei": ("qei", "fused"),
    "nelder-mead": ("nelder-mead", "fused"),
    "tpe": ("tpe", "fused"),
    "random": ("random", "fused"),
    "qei-onehot": ("qei", "onehot"),
    "qei-mixed": ("qei", "mixed"),
}
"""Method -> (proposer, encoding). The encoding matters only for multi-structure tasks.
``qei-mixed`` is the current default (issue 12: the mixed encoding, the structure
kernel, axis features and GPSampler-style acquisition), measured from a later commit
(``--code``) whose tasks and learners are the pinned ones."""
PLAIN_ONLY_MULTI = {"qei-onehot"}
VAR = REPO / "var" / "paper"


@dataclass(frozen=True)
class Cell:
    task: str
    method: str
    learner: str
    seed: int
    budget: int
    tag: str = ""
    """Names an extra measurement (its own results file), e.g. ``b30`` for longer budgets."""

    @property
    def label(self) -> str:
        return f"{self.method}-{self.tag}" if self.tag else self.method

    @property
    def key(self) -> str:
        return f"{self.task}|{self.label}|{self.learner}|{self.seed}"

    @property
    def name(self) -> str:
        return f"paper-{self.task}-{self.label}-{self.learner}-s{self.seed}"


def results_path(learner: str, quick: bool, tag: str = "") -> Path:
    suffix = f"-{tag}" if tag else ""
    return (QUICK if quick else RESULTS) / f"paper-{learner}{suffix}.jsonl"


def grid(
    tasks: list[str],
    methods: list[str],
    learner: str,
    seeds: int,
    model_budget: int,
    baseline_budget: int,
    tag: str = "",
) -> list[Cell]:
    """Seed-major order, so a partial run has every method at the first seeds."""
    cells = []
    for seed in range(seeds):
        for task in tasks:
            multi = _structures(task) > 1
            for method in methods:
                if method in PLAIN_ONLY_MULTI and not multi:
                    continue
                proposer = METHODS[method][0]
                budget = model_budget if proposer == "qei" else baseline_budget
                cells.append(Cell(task, method, learner, seed, budget, tag))
    return cells


def _structures(task: str) -> int:
    structures = study_body(task)["space"]["structures"]
    return 2 if structures == "all" else len(structures)


def study_create(
    cell: Cell, train_steps: int | None, space: dict[str, Any] | None = None
) -> dict[str, Any]:
    body = study_body(cell.task)
    proposer, encoding = METHODS[cell.method]
    body["name"] = cell.name
    body["proposer"] = {**body.get("proposer", {}), "name": proposer, "seed": cell.seed}
    body["task"] = {**body["task"], "learner": cell.learner, "seed": cell.seed}
    if train_steps is not None:
        body["task"]["train_steps"] = train_steps
    if _structures(cell.task) > 1:
        body["space"]["encoding"] = encoding
    body["space"].update(space or {})
    body["max_trials"] = cell.budget
    body["metadata"] = {**body.get("metadata", {}), "bench": "paper", "cell": cell.key}
    return body


# -- the service under test ------------------------------------------------------------


class Service:
    """One adserver (SQLite) and one ``adworker --concurrency N``, from the pinned code."""

    def __init__(self, workdir: Path, workers: int) -> None:
        from adclient.testing.servers import ServerProcess

        self.workdir = workdir
        workdir.mkdir(parents=True, exist_ok=True)
        # the pinned code reaches both processes through PYTHONPATH (use_snapshot)
        self.server = ServerProcess(
            database_url=f"sqlite:///{workdir / 'studies.db'}", workdir=workdir
        )
        self.workers = workers
        self.worker: subprocess.Popen[bytes] | None = None

    def __enter__(self) -> Service:
        self.server.start()
        adworker = Path(sys.executable).with_name("adworker")
        log = (self.workdir / "adworker.log").open("ab")
        self.worker = subprocess.Popen(
            [
                str(adworker),
                "--server",
                self.server.url,
                "--concurrency",
                str(self.workers),
                "--poll",
                "0.2",
                "--worker-id",
                "paper",
                "--log-level",
                "warning",
            ],
            env={**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"},
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        return self

    def __exit__(self, *exc: object) -> None:
        if self.worker is not None and self.worker.poll() is None:
            # twice: the first lets a job finish, the second abandons it
            self.worker.send_signal(signal.SIGTERM)
            try:
                self.worker.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.worker.send_signal(signal.SIGTERM)
                try:
                    self.worker.wait(timeout=15)
                except subprocess.TimeoutExpired:
                    os.killpg(self.worker.pid, signal.SIGKILL)
                    self.worker.wait()
        self.server.stop()

    @property
    def url(self) -> str:
        return self.server.url

    def check(self) -> None:
        if self.worker is not None and self.worker.poll() is not None:
            raise RuntimeError(
                f"adworker exited ({self.worker.returncode}); see {self.workdir / 'adworker.log'}"
            )


def run_cell(
    client: Any,
    service: Service,
    cell: Cell,
    body: dict[str, Any],
    progress: Any,
    bar: Any,
    png_dir: Path,
    code: str,
    space: dict[str, Any],
) -> dict[str, Any]:
    """Create the study, wait for its budget to be spent, and gather what the table needs."""
    from adclient.client import study_finished

    load_before = os.getloadavg()[0]
    started = time.perf_counter()
    study = client.create_study(body)
    progress.reset(bar, total=cell.budget, description=f"{cell.key}")
    while True:
        info = study.refresh()
        done = info.n_complete + info.n_failed
        best = f"best {info.best_value:.4f}" if info.best_value is not None else ""
        progress.update(bar, completed=done, description=f"{cell.key} {best}")
        if study_finished(info):
            break
        service.check()
        time.sleep(0.5)
    wall = time.perf_counter() - started
    trials = sorted(client.trials(info.id), key=lambda t: t.number)
    created = info.created_at
    rows = []
    for trial in trials:
        ask = trial.info.get("fit_seconds", 0.0) + trial.info.get("acq_seconds", 0.0)
        rows.append(
            {
                "number": trial.number,
                "state": str(trial.state.value),
                "value": trial.value,
                "finished_s": (trial.finished_at - created).total_seconds()
                if trial.finished_at
                else None,
                "worker_s": trial.metrics.get("time_total_s"),
                "ask_s": round(float(ask), 4),
                "how": trial.info.get("method"),
                "structure": trial.params.get("structure"),
            }
        )
    record: dict[str, Any] = {
        "key": cell.key,
        "task": cell.task,
        "method": cell.method,
        "tag": cell.tag,
        "space": space,
        "proposer": METHODS[cell.method][0],
        "encoding": METHODS[cell.method][1],
        "learner": cell.learner,
        "seed": cell.seed,
        "budget": cell.budget,
        "study_id": info.id,
        "wall_s": wall,
        "load_before": load_before,
        "load_after": os.getloadavg()[0],
        "code": code,
        "finished": datetime.now().isoformat(timespec="seconds"),
        "trials": rows,
    }
    best_trial = client.best_trial(info.id)
    if best_trial is not None:
        record["best"] = {
            "trial_id": best_trial.id,
            "number": best_trial.number,
            "value": best_trial.value,
            "params": best_trial.params,
        }
        try:
            data = client.get_artifact(best_trial.id, "robot.png")
        except Exception as error:  # a missing picture is no reason to stop
            record["png_error"] = str(error)
        else:
            png_dir.mkdir(parents=True, exist_ok=True)
            path = png_dir / f"{cell.task}-{cell.label}-s{cell.seed}.png"
            path.write_bytes(data)
            record["png"] = str(path.relative_to(REPO))
    return record


def warm_up(client: Any, service: Service, learner: str, progress: Any, bar: Any) -> None:
    """Two cheap jobs first, so the first measured study does not pay for the worker
    processes' imports (PyBullet, and torch for an RL learner)."""
    from adclient.client import study_finished

    body = study_body("diagonal-gesture")
    body.update(name="paper-warmup", max_trials=2, metadata={"bench": "paper-warmup"})
    body["proposer"] = {"name": "random", "seed": 0}
    body["task"] = {**body["task"], "learner": learner}
    if learner != "fast":
        body["task"]["train_steps"] = 64
    study = client.create_study(body)
    progress.update(bar, description="warming up the workers")
    while not study_finished(study.refresh()):
        service.check()
        time.sleep(0.5)


def run(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
    )

    console = Console()
    learner = args.learner
    workers_checked = False
    if args.code and learner == "fast":
        # the fast learner's scores must be the pinned code's: re-score stored designs
        check = subprocess.run(
            [
                sys.executable,
                str(REPO / "bench" / "fast_scores_check.py"),
                "--tolerance",
                str(args.score_tolerance),
            ]
        )
        workers_checked = check.returncode == 0
    code, _ = use_snapshot(quick=args.quick, ref=args.code, workers_checked=workers_checked)
    from adclient.client import Client

    seeds = args.seeds or DEFAULT_SEEDS.get(learner, RL_SEEDS)
    model_budget, baseline_budget = args.budget, args.baseline_budget
    if args.quick:
        seeds = args.seeds or 1
        model_budget = baseline_budget = 5
    cells = grid(args.tasks, args.methods, learner, seeds, model_budget, baseline_budget, args.tag)
    path = results_path(learner, args.quick, args.tag)
    done = {record["key"] for record in read_jsonl(path)}
    todo = [cell for cell in cells if cell.key not in done]
    console.print(
        f"{len(cells)} cells ({learner}, {seeds} seeds), {len(cells) - len(todo)} done; "
        f"results: {path}; code {code}"
    )
    if not todo:
        return report(console, quick=args.quick)
    workdir = QUICK / "service" if args.quick else VAR / learner
    png_dir = workdir / "png"
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn())
    started = time.perf_counter()
    with (
        Service(workdir, args.workers) as service,
        Client(service.url, timeout=60) as client,
        Progress(*columns, TimeElapsedColumn(), console=console) as progress,
    ):
        # leftovers of an interrupted run would compete for the workers: stop them
        for study in client.studies():
            if study.state.value == "running" and study.name.startswith("paper-"):
                client.stop_study(study.id)
        overall = progress.add_task("studies", total=len(cells), completed=len(cells) - len(todo))
        bar = progress.add_task("", total=1)
        warm_up(client, service, learner, progress, bar)
        for cell in todo:
            body = study_create(cell, args.train_steps, args.space)
            record = run_cell(client, service, cell, body, progress, bar, png_dir, code, args.space)
            append_jsonl(path, record)
            progress.advance(overall)
    console.print(f"ran {len(todo)} studies in {time.perf_counter() - started:.0f} s")
    return report(console, quick=args.quick)


def report(console: Any, *, quick: bool) -> int:
    from bench.paper_report import write_report

    write_report(console, quick=quick)
    return 0


def _space_override(text: str) -> tuple[str, Any]:
    import yaml

    key, sep, value = text.partition("=")
    if not sep or not key:
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE, got {text!r}")
    return key, yaml.safe_load(value)


def main(argv: list[str] | None = None) -> int:
    interrupt_on_sigterm()
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--learner", default="fast", help="fast (default) or ddpg, td3, sac, ppo")
    parser.add_argument("--seeds", type=int, help="seeds per cell (default 10 fast, 3 RL)")
    parser.add_argument(
        "--tasks", type=lambda s: s.split(","), default=list(TASKS), help="comma-separated"
    )
    parser.add_argument(
        "--methods",
        type=lambda s: s.split(","),
        default=[m for m in METHODS if m != "qei-mixed"],
        help="comma-separated (qei-mixed needs --code)",
    )
    parser.add_argument("--budget", type=int, default=MODEL_BUDGET, help="qei's evaluations")
    parser.add_argument(
        "--baseline-budget", type=int, default=BASELINE_BUDGET, help="other methods' evaluations"
    )
    parser.add_argument("--train-steps", type=int, help="override the learner's step budget")
    parser.add_argument(
        "--tag",
        default="",
        help="an extra measurement beside the grid (own results file; methods shown as "
        "METHOD-TAG), e.g. --tag b30 --budget 30 --methods qei",
    )
    parser.add_argument(
        "--space",
        type=_space_override,
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="with --tag only: set a space option (YAML value), e.g. --tag d30 "
        "--space embedding_max_dim=30; repeatable",
    )
    parser.add_argument(
        "--code",
        help="run this commit instead of the pinned one (refused if workers/ differs), "
        "e.g. --methods qei-mixed --code HEAD",
    )
    parser.add_argument(
        "--score-tolerance",
        type=float,
        default=0.0,
        help="with --code: the largest difference from the pinned code's fast-learner "
        "scores still taken as the same tasks (bench/fast_scores_check.py); say it with "
        "the results",
    )
    parser.add_argument("--workers", type=int, default=2, help="adworker --concurrency")
    parser.add_argument("--quick", action="store_true", help="smoke run: 1 seed, 5 evaluations")
    parser.add_argument("--report", action="store_true", help="only rewrite tables and plots")
    args = parser.parse_args(argv)
    for task in args.tasks:
        if task not in TASKS:
            parser.error(f"unknown task {task!r}; known: {', '.join(TASKS)}")
    for method in args.methods:
        if method not in METHODS:
            parser.error(f"unknown method {method!r}; known: {', '.join(METHODS)}")
    if "qei-mixed" in args.methods and not args.code and not args.quick:
        parser.error("qei-mixed needs --code: a commit with the mixed encoding, e.g. HEAD")
    if args.tag and not re.fullmatch(r"[a-z0-9]+", args.tag):
        parser.error("--tag: lower-case letters and digits only")
    if args.space and not args.tag:
        parser.error("--space changes the study: name the measurement with --tag")
    args.space = dict(args.space)
    if args.report:
        from rich.console import Console

        return report(Console(), quick=args.quick)
    return run(args)


if __name__ == "__main__":
    raise SystemExit(main())
