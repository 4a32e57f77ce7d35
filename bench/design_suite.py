"""Synthetic design-space objectives: the service's proposers against Optuna's, 30 evaluations.

The objectives, each a score in [0, 1] of a decoded robot design (tree + specs), and
their families are in client/adclient/testing/design_objectives.py (shared with the tests).

Methods:
- ``qei``: the service's default (the ``mixed`` encoding), ``qei-fused`` (the
  preprint's encoding), ``qei-onehot``: a real ``adserver`` on a SQLite file, plain
  ask/tell over HTTP, one trial at a time, proposer defaults.
- ``gp-optuna``, ``tpe-optuna``, ``random-optuna``: Optuna's GPSampler, TPESampler and
  RandomSampler in-process with their defaults (GPSampler: deterministic_objective),
  the structure as a categorical and every spec as a float in its physical range.

Every method and seed gets the same budget. The report gives, per objective and method,
the median and lower quartile of the best score by 30 and the trees a run tried, and
issue 26's goals: qei's median at or above GPSampler's, its lower quartile at or above
random search's. Results append to ``--results`` (a rerun resumes).

Run: ``.venv/bin/python bench/design_suite.py`` (20 seeds, every objective, the default
methods; writes bench/RESULTS.md). Issue 26 ran two halves side by side, each with its
own server and results file, then reported them together:

    M="qei gp-optuna tpe-optuna random-optuna"
    .venv/bin/python bench/design_suite.py --seeds 10 --methods $M --no-write
    .venv/bin/python bench/design_suite.py --seeds 10 --first-seed 10 --methods $M \\
        --results bench/results/design_suite-i26b.jsonl --no-write
    cat bench/results/design_suite-i26b.jsonl >> bench/results/design_suite-i26.jsonl
    .venv/bin/python bench/design_suite.py --report

Issue 37 ran the spec-dominated objectives with this branch's server and, beside it,
main's (a worktree of main first on PYTHONPATH, its runs labelled ``qei-main``), then
reported the files together (a run appears once however many files hold it):

    S="spec-dominated-1 spec-dominated-2 spec-dominated-3 spec-dominated-4"
    .venv/bin/python bench/design_suite.py --seeds 10 --objectives $S \
        --methods qei gp-optuna random-optuna --no-write \
        --results bench/results/design_suite-i37.jsonl
    PYTHONPATH=$MAIN/client:$MAIN/service:$MAIN/workers:$PWD .venv/bin/python \
        bench/design_suite.py --seeds 10 --objectives $S --methods qei --label qei=qei-main \
        --results bench/results/design_suite-i37-main.jsonl --no-write
    cat bench/results/design_suite-i37*.jsonl > /tmp/i37.jsonl
    .venv/bin/python bench/design_suite.py --report --results /tmp/i37.jsonl --no-write

The judged second looks (an option; the default was ``off`` then) ran this branch's
server alone, two halves side by side, and were reported with the runs of main before
them (its spec-dominated runs and issue 26's qei runs relabelled ``qei-main``,
GPSampler's and random search's) gathered into one file, as bench/RESULTS.md's
wrong-tree section says:

    .venv/bin/python bench/design_suite.py --seeds 6 --objectives $S spec-dominated-5 \
        spec-dominated-6 --methods qei --no-write \
        --results bench/results/design_suite-i37-judged.jsonl
    .venv/bin/python bench/design_suite.py --seeds 6 --objectives additive-trap \
        shifted-optima tree-similarity specs-only unused-specs interaction \
        --methods qei --no-write --results bench/results/design_suite-i37-judged-i26.jsonl

A qei option runs through HTTP with ``--proposer-options`` and its own label (issue 37's
judged looks on today's code, a second file with ``--first-seed 10`` beside it):

    .venv/bin/python bench/design_suite.py --seeds 10 --methods qei --label qei=qei-judged \
        --proposer-options '{"second_looks": "judged"}' --no-write \
        --results bench/results/design_suite-i37-20-judged-d14fcf2.jsonl

The Thompson looks, the default since e799752, ran the same way, each half into its own
file, reported beside the runs of ``off`` (design_suite-i37-20-d14fcf2.jsonl relabelled
``qei-off``) and the recorded GPSampler, TPE and random search runs:

    .venv/bin/python bench/design_suite.py --seeds 10 --methods qei --no-write \
        --results bench/results/design_suite-i37-20-e799752.jsonl
    # and --first-seed 10, then both halves in one file

``--starts-per-tree K`` sets the qei studies' ``n_initial`` to K times their trees (at
most 16), so the covering start gives each tree K random designs (issue 37's two per
tree: ``--label qei=qei-two --starts-per-tree 2``).

Issue 61 added the floor traps (``adclient.testing.tree_traps``: floor-8, floor-16,
needle-floor-32, needle-floor-64), where a tree's first random design says almost
nothing, and ran the default (``floor_looks``) beside ``floor_looks: false`` (the
default before it), each into its own file, then reported them with the recorded
GPSampler, TPE and random-search runs and the traps' own (bench/RESULTS.md, "Floor
looks"):

    .venv/bin/python bench/design_suite.py --seeds 20 --methods qei --no-write \
        --results bench/results/design_suite-i61-floor.jsonl
    .venv/bin/python bench/design_suite.py --seeds 20 --methods qei --label qei=qei-today \
        --proposer-options '{"floor_looks": false}' --no-write \
        --results bench/results/design_suite-i61-today.jsonl

``--seeds 2 --no-write --results /tmp/x.jsonl`` while developing.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
import warnings
from pathlib import Path
from typing import Any

import httpx
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from adclient.decode import build_design, spec_layout  # noqa: E402
from adclient.design import DesignSpace  # noqa: E402
from adclient.designs import Design  # noqa: E402
from adclient.testing.design_objectives import (  # noqa: E402
    EIGHT_TREES,
    LIMBS5_STRUCTURES,
    OBJECTIVES,
    Objective,
)
from adclient.testing.servers import ServerProcess  # noqa: E402
from adclient.testing.tree_traps import FLOOR_TRAPS  # noqa: E402
from adservice.proposers.initial import COVERED_CHOICES  # noqa: E402
from bench.proposer_results import write_subsection  # noqa: E402

SUITE = {
    **OBJECTIVES,
    **{name: Objective(name, space, score) for name, (space, score) in FLOOR_TRAPS.items()},
}
"""The suite's objectives: design_objectives' and (issue 61) the floor traps."""
SUITE_EIGHT_TREES = EIGHT_TREES | {
    name for name, (space, _) in FLOOR_TRAPS.items() if space["structures"] == LIMBS5_STRUCTURES
}

RESULTS_PATH = ROOT / "bench" / "results" / "design_suite-i26.jsonl"
"""Issue 26's runs (the code before it: ``design_suite.jsonl``, 10 seeds, 4 objectives)."""
BUDGET = 30

SERVICE_METHODS = {"qei": None, "qei-fused": "fused", "qei-onehot": "onehot"}
OPTUNA_METHODS = ("gp-optuna", "tpe-optuna", "random-optuna")
DEFAULT_METHODS = ["qei", "gp-optuna", "tpe-optuna", "random-optuna", "qei-onehot"]
BASELINE = "qei-main"
"""The label of a baseline's qei runs (``--label qei=qei-main``: another checkout's
server, its code on PYTHONPATH), reported beside the others."""


def design_from_params(space: DesignSpace, params: dict[str, Any]) -> Design:
    """The design a trial's readable params (``design_params``) or Optuna params name."""
    layout = spec_layout(space)
    values = {key: float(params[key]) for key in layout.names if key in params}
    return build_design(space, layout, int(params["structure_index"]), values)


def run_service(
    http: httpx.Client,
    objective: Objective,
    method: str,
    seed: int,
    options: dict[str, Any] | None = None,
    starts_per_tree: int | None = None,
) -> dict:
    """One study of ``method`` on ``objective`` through HTTP; ``options``: the qei
    proposer's options (``--proposer-options``), the defaults when None;
    ``starts_per_tree``: the study's ``n_initial`` is that many times its trees, at most
    ``COVERED_CHOICES`` (``--starts-per-tree``)."""
    space = dict(objective.space)
    encoding = SERVICE_METHODS[method]
    if encoding is not None:
        space["encoding"] = encoding
    parsed = DesignSpace.model_validate(space)
    proposer: dict[str, Any] = {"name": "qei", "seed": seed}
    if options:
        proposer["options"] = options
    if starts_per_tree is not None:
        trees = len(parsed.tree_structures())
        proposer["n_initial"] = min(starts_per_tree * trees, COVERED_CHOICES)
    created = http.post(
        "/api/v1/studies",
        json={
            "name": f"{objective.name}-{method}-{seed}-{time.time_ns()}",
            "direction": "maximize",
            "space": space,
            "proposer": proposer,
            "max_trials": BUDGET,
        },
    )
    created.raise_for_status()
    study_id = created.json()["id"]
    values, asks, trees = [], [], []
    for _ in range(BUDGET):
        started = time.perf_counter()
        asked = http.post(f"/api/v1/studies/{study_id}/ask", json={"count": 1})
        asks.append(time.perf_counter() - started)
        asked.raise_for_status()
        (trial,) = asked.json()["trials"]
        value = objective.score(design_from_params(parsed, trial["params"]))
        told = http.post(f"/api/v1/trials/{trial['id']}/tell", json={"value": value})
        told.raise_for_status()
        values.append(value)
        trees.append(int(trial["params"]["structure_index"]))
    return {"values": values, "ask_seconds": asks, "trees": trees}


def run_optuna(objective: Objective, method: str, seed: int) -> dict:
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    space = DesignSpace.model_validate(objective.space)
    layout = spec_layout(space)
    sampler: optuna.samplers.BaseSampler
    if method == "gp-optuna":
        sampler = optuna.samplers.GPSampler(seed=seed, deterministic_objective=True)
    elif method == "tpe-optuna":
        sampler = optuna.samplers.TPESampler(seed=seed)
    else:
        sampler = optuna.samplers.RandomSampler(seed=seed)
    study = optuna.create_study(direction="maximize", sampler=sampler)
    values, asks, trees = [], [], []
    count = len(layout.structures)
    for _ in range(BUDGET):
        started = time.perf_counter()
        trial = study.ask()
        params: dict[str, Any] = {
            "structure_index": trial.suggest_categorical("structure_index", list(range(count)))
        }
        for k, key in enumerate(layout.names):
            params[key] = trial.suggest_float(
                key, float(layout.low[k]), float(layout.high[k]), log=bool(layout.log[k])
            )
        asks.append(time.perf_counter() - started)
        value = objective.score(design_from_params(space, params))
        study.tell(trial, value)
        values.append(value)
        trees.append(int(params["structure_index"]))
    return {"values": values, "ask_seconds": asks, "trees": trees}


def read_results(path: Path) -> list[dict]:
    """The runs of a results file, the first of each (objective, method, seed): files of
    runs side by side can be concatenated."""
    if not path.exists():
        return []
    runs: dict[tuple[str, str, int], dict] = {}
    for line in path.read_text().splitlines():
        if line.strip():
            record = json.loads(line)
            runs.setdefault((record["objective"], record["method"], record["seed"]), record)
    return list(runs.values())


def best_by(values: list[float], n: int) -> float:
    return float(max(values[:n]))


def mann_whitney(a: list[float], b: list[float]) -> float:
    from scipy.stats import mannwhitneyu

    if len(a) < 2 or len(b) < 2 or (len(set(a)) == 1 and set(a) == set(b)):
        return 1.0
    return float(mannwhitneyu(a, b, alternative="two-sided").pvalue)


def report(records: list[dict], subject: str = "qei") -> str:
    """Per objective and method (every label in ``records``): the median and lower
    quartile of the best score by ``BUDGET``, the median number of trees a run tried,
    and the issue-26 and -37 goals for ``subject`` (a label: ``qei``, or an option's
    runs, ``qei-judged``): its median at or above GPSampler's, its lower quartile and
    every seed at or above random search's lower quartile."""
    known = [*DEFAULT_METHODS, BASELINE]
    labels = {r["method"] for r in records}
    methods = [m for m in known if m in labels] + sorted(labels - set(known))
    methods = [subject, *(m for m in methods if m != subject)]
    lines = [
        f"Best score by {BUDGET} evaluations over seeds: median / lower quartile "
        f"(trees tried, median), n seeds. Goals (issues 26 and 37): {subject}'s median at "
        f"or above GPSampler's, {subject}'s lower quartile, and (issue 37) every seed of "
        f"{subject}, at or above random search's lower quartile; its worst seed beside it.",
        "",
        "| objective | "
        + " | ".join(methods)
        + f" | median vs GP | q1 vs random | {subject} worst seed (of base) | every seed |",
        "| --- | " + " | ".join("---" for _ in methods) + " | --- | --- | --- | --- |",
    ]
    for name in SUITE:
        rows = {
            m: [r for r in records if r["objective"] == name and r["method"] == m] for m in methods
        }
        if not rows.get(subject):
            continue
        cells, medians, quartiles = [], {}, {}
        for m in methods:
            best = [best_by(r["values"], BUDGET) for r in rows[m]]
            if not best:
                cells.append("-")
                continue
            q1, q2 = np.percentile(best, [25, 50])
            medians[m], quartiles[m] = q2, q1
            trees = [len(set(r["trees"])) for r in rows[m] if "trees" in r]
            tried = f" ({np.median(trees):g})" if trees else ""
            cells.append(f"{q2:.3f} / {q1:.3f}{tried}, n={len(best)}")
        gp, random = medians.get("gp-optuna"), quartiles.get("random-optuna")
        verdict_gp = "-" if gp is None else ("met" if medians[subject] >= gp else "**missed**")
        verdict_random = (
            "-" if random is None else ("met" if quartiles[subject] >= random else "**missed**")
        )
        if gp is not None:
            p = mann_whitney(
                [best_by(r["values"], BUDGET) for r in rows[subject]],
                [best_by(r["values"], BUDGET) for r in rows["gp-optuna"]],
            )
            verdict_gp += f" (p = {p:.2f})"
        worst = {m: min(best_by(r["values"], BUDGET) for r in rows[m]) for m in medians}
        worst_cell = f"{worst[subject]:.3f}" + (
            f" ({worst[BASELINE]:.3f})" if BASELINE in worst else ""
        )
        every = "-" if random is None else ("met" if worst[subject] >= random else "**missed**")
        lines.append(
            f"| {name} | "
            + " | ".join(cells)
            + f" | {verdict_gp} | {verdict_random} | {worst_cell} | {every} |"
        )
    ask = {
        m: np.median([s for r in records if r["method"] == m for s in r["ask_seconds"]])
        for m in methods
    }
    late = {
        m: np.median(
            [
                s
                for r in records
                if r["method"] == m and r["objective"] in SUITE_EIGHT_TREES
                for s in r["ask_seconds"][BUDGET - 3 :]
            ]
        )
        for m in methods
    }
    lines += [
        "",
        "Median seconds per ask over every run (qei through HTTP on a loopback adserver, "
        "Optuna in-process): " + ", ".join(f"{m} {ask[m]:.3f}" for m in methods) + ".",
        "",
        f"The last three asks (n = {BUDGET - 3} to {BUDGET - 1}) on the 8-tree, 13-spec space: "
        + ", ".join(f"{m} {late[m]:.3f} s" for m in methods)
        + f" (goal: {subject} under 0.5 s).",
    ]
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--objectives", nargs="+", default=list(SUITE))
    parser.add_argument("--methods", nargs="+", default=DEFAULT_METHODS)
    parser.add_argument("--results", type=Path, default=RESULTS_PATH, help="JSON lines, resumed")
    parser.add_argument("--no-write", action="store_true")
    parser.add_argument("--report", action="store_true", help="only rewrite the report")
    parser.add_argument(
        "--label",
        default=None,
        help="METHOD=LABEL: record METHOD's runs as LABEL (a baseline: qei=qei-main)",
    )
    parser.add_argument(
        "--proposer-options",
        type=json.loads,
        default=None,
        help='JSON: the qei methods\' proposer options (\'{"second_looks": "judged"}\'); '
        "label the runs with --label",
    )
    parser.add_argument(
        "--starts-per-tree",
        type=int,
        default=None,
        help="the qei methods' n_initial: this many times the space's trees, at most 16 "
        "(2: two random start designs per tree on 8 trees); label the runs with --label",
    )
    parser.add_argument(
        "--subject", default="qei", help="the label the goals judge in the report (qei-judged)"
    )
    args = parser.parse_args()
    if args.starts_per_tree is not None and args.starts_per_tree < 1:
        parser.error(f"--starts-per-tree: {args.starts_per_tree} is under 1")
    warnings.filterwarnings("ignore")
    labels = dict([args.label.split("=", 1)]) if args.label else {}
    if not args.report:
        done = {(r["objective"], r["method"], r["seed"]) for r in read_results(args.results)}
        done = {
            (o, m, s) for o, label, s in done for m in args.methods if labels.get(m, m) == label
        }
        todo = [
            (objective, method, seed)
            for seed in range(args.first_seed, args.first_seed + args.seeds)
            for objective in args.objectives
            for method in args.methods
            if (objective, method, seed) not in done
        ]
        args.results.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory() as workdir:
            server = ServerProcess(
                database_url=f"sqlite:///{workdir}/suite.db", workdir=Path(workdir)
            ).start()
            try:
                with httpx.Client(base_url=server.url, timeout=300) as http:
                    for number, (name, method, seed) in enumerate(todo, start=1):
                        objective = SUITE[name]
                        started = time.perf_counter()
                        if method in SERVICE_METHODS:
                            result = run_service(
                                http,
                                objective,
                                method,
                                seed,
                                args.proposer_options,
                                args.starts_per_tree,
                            )
                        else:
                            result = run_optuna(objective, method, seed)
                        label = labels.get(method, method)
                        record = {"objective": name, "method": label, "seed": seed, **result}
                        with args.results.open("a") as out:
                            out.write(json.dumps(record) + "\n")
                        print(
                            f"[{number}/{len(todo)}] {name} {method} seed {seed}: best "
                            f"{max(result['values']):.3f}, {len(set(result['trees']))} trees, "
                            f"in {time.perf_counter() - started:.1f} s",
                            flush=True,
                        )
            finally:
                server.stop()
    text = report(read_results(args.results), args.subject)
    print(text)
    if not args.no_write:
        write_subsection("### Design-space suite, issue 26 (bench/design_suite.py)", text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
