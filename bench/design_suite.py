"""Synthetic design-space objectives: the service's proposers against Optuna's, 30 evaluations.

Each objective scores a decoded robot design (tree + specs) in [0, 1], so every method
optimises the identical function of the design.

Multiplicative families (issue 12): a wrong tree scores low whatever its specs.

- ``tree-similarity`` (8 trees of 3 to 5 links, 13 specs): the score falls with the
  tree's edit distance (edges added or removed) to a target tree, times how well the
  lengths and joint axes match targets. Structure similarity matters strongly.
- ``specs-only`` (the same space): only specs every tree has count (the lengths of a
  and b, the axis of b); the tree does not matter at all.
- ``unused-specs`` (the same space): the best trees are the ones with limb e, and
  then e's length and axis decide; the other trees only get a weaker score from b.
  The specs that matter are unused by half of the trees.
- ``interaction`` (4 trees of 4 links, lengths, radii and axes: 14 specs): every tree
  has its own optimal lengths and axes and its own ceiling; nothing carries over.

Additive families (issue 26): a tree's value adds to a spec term, so a wrong tree keeps
scoring a little better as its specs improve, the trap of a search that believes the
trees it has not seen behave like the ones it has (see the functions' docstrings).

- ``additive-trap`` (the 8-tree space): the best tree is the smallest, a-b-c.
- ``shifted-optima`` (the 8-tree space): each tree's best specs lie near, not at, a
  shared optimum; the best tree is the star a-(b, c, d).
- ``needle-16`` (every tree of 4 links: 16, 14 specs): one tree far better, unrelated
  to how alike the trees are.
- ``tree-shape-64`` (64 of the 125 trees of 5 links): the tree's value follows its
  shape (depth, leaves, root degree), so alike trees score alike.

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

``--seeds 2 --no-write --results /tmp/x.jsonl`` while developing.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.servers import ServerProcess  # noqa: E402

from adclient.decode import build_design, spec_layout  # noqa: E402
from adclient.design import DesignSpace  # noqa: E402
from adclient.designs import Design  # noqa: E402
from bench.proposer_results import write_subsection  # noqa: E402

RESULTS_PATH = ROOT / "bench" / "results" / "design_suite-i26.jsonl"
"""Issue 26's runs (the code before it: ``design_suite.jsonl``, 10 seeds, 4 objectives)."""
BUDGET = 30
PI = math.pi

LIMBS5_STRUCTURES = [
    [["a", "b"], ["b", "c"]],
    [["a", "b"], ["b", "c"], ["c", "d"]],
    [["a", "b"], ["b", "c"], ["c", "d"], ["d", "e"]],
    [["a", "b"], ["b", "c"], ["b", "d"]],
    [["a", "b"], ["a", "c"], ["a", "d"]],
    [["a", "b"], ["b", "c"], ["c", "e"]],
    [["a", "b"], ["b", "c"], ["b", "d"], ["b", "e"]],
    [["a", "b"], ["b", "c"], ["c", "d"], ["c", "e"]],
]
ARMS4_STRUCTURES = [
    [["a", "b"], ["b", "c"], ["c", "d"]],
    [["a", "b"], ["a", "c"], ["a", "d"]],
    [["a", "b"], ["b", "c"], ["b", "d"]],
    [["a", "b"], ["a", "c"], ["c", "d"]],
]


def limbs5_space() -> dict[str, Any]:
    return {
        "type": "design",
        "parts": {"link": {"length": {"low": 0.1, "high": 0.5}, "radius": 0.04, "mass": 1.0}},
        "instances": [{"name": name, "part": "link"} for name in "abcde"],
        "structures": LIMBS5_STRUCTURES,
    }


def arms4_space() -> dict[str, Any]:
    return {
        "type": "design",
        "parts": {
            "link": {
                "length": {"low": 0.1, "high": 0.5},
                "radius": {"low": 0.02, "high": 0.08},
                "mass": 1.0,
            }
        },
        "instances": [{"name": name, "part": "link"} for name in "abcd"],
        "structures": ARMS4_STRUCTURES,
    }


def _unit(rng: np.random.Generator) -> np.ndarray:
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def _alignment(design: Design, targets: dict[str, np.ndarray]) -> float:
    """Mean squared cosine between each joint's axis and its target (sign-free)."""
    values = [
        float(np.dot(joint.axis, targets[joint.child])) ** 2
        for joint in design.joints
        if joint.child in targets
    ]
    return float(np.mean(values)) if values else 0.0


def _lengths(design: Design) -> dict[str, float]:
    return {link.name: link.length for link in design.links}


def tree_similarity() -> Callable[[Design], float]:
    rng = np.random.default_rng(101)
    target_edges = {tuple(edge) for edge in LIMBS5_STRUCTURES[2]}
    axes = {name: _unit(rng) for name in "bcde"}
    lengths = {name: float(rng.uniform(0.15, 0.45)) for name in "abcde"}

    def score(design: Design) -> float:
        edges = set(design.edges())
        structure = math.exp(-len(edges ^ target_edges) / 2.0)
        own = _lengths(design)
        fit = math.exp(-sum((own[k] - lengths[k]) ** 2 for k in own) / 0.05)
        return structure * fit * (0.3 + 0.7 * _alignment(design, axes))

    return score


def specs_only() -> Callable[[Design], float]:
    rng = np.random.default_rng(202)
    axis_b = _unit(rng)

    def score(design: Design) -> float:
        own = _lengths(design)
        fit = math.exp(-((own["a"] - 0.35) ** 2 + (own["b"] - 0.2) ** 2) / 0.02)
        return fit * (0.2 + 0.8 * _alignment(design, {"b": axis_b}))

    return score


def unused_specs() -> Callable[[Design], float]:
    rng = np.random.default_rng(303)
    axis_b, axis_e = _unit(rng), _unit(rng)

    def score(design: Design) -> float:
        own = _lengths(design)
        if "e" in own:
            fit = math.exp(-((own["e"] - 0.42) ** 2) / 0.01)
            return 0.3 + 0.7 * fit * _alignment(design, {"e": axis_e})
        return 0.5 * _alignment(design, {"b": axis_b})

    return score


def interaction() -> Callable[[Design], float]:
    rng = np.random.default_rng(404)
    ceilings = [1.0, 0.9, 0.8, 0.7]
    per_tree = [
        (
            {name: float(rng.uniform(0.15, 0.45)) for name in "abcd"},
            {name: float(rng.uniform(0.03, 0.07)) for name in "abcd"},
            {name: _unit(rng) for name in "bcd"},
        )
        for _ in ARMS4_STRUCTURES
    ]

    def score(design: Design) -> float:
        lengths, radii, axes = per_tree[design.structure_index]
        misfit = sum((link.length - lengths[link.name]) ** 2 for link in design.links) / 0.04
        misfit += sum((link.radius - radii[link.name]) ** 2 for link in design.links) / 0.001
        fit = math.exp(-misfit)
        return ceilings[design.structure_index] * fit * (0.3 + 0.7 * _alignment(design, axes))

    return score


# -- additive families: a wrong tree keeps improving with its specs (issue 26) ------
#
# Each score is ``w * tree_value[tree] + (1 - w) * spec_term``: a study that settles
# on a wrong tree still sees its score rise as its specs improve, which is the trap a
# model falls into when it believes unseen trees behave like the ones it has seen.
# Which tree is best is drawn from each objective's own generator, so it is rarely
# among a study's first designs.


def _tree_values(
    rng: np.random.Generator, count: int, worst: float, runner_up: float, best: int | None = None
) -> np.ndarray:
    """One best tree at 1 (``best``, else drawn), the others uniform in [worst, runner_up]."""
    values = rng.uniform(worst, runner_up, size=count)
    values[rng.integers(count) if best is None else best] = 1.0
    return values


def additive_trap() -> Callable[[Design], float]:
    """8 trees; the tree counts 45%, lengths and axes every tree has count 55%. The
    best tree is the smallest (a-b-c), the one with the fewest specs to search."""
    rng = np.random.default_rng(505)
    tree_values = _tree_values(rng, len(LIMBS5_STRUCTURES), 0.0, 0.35, best=0)
    axes = {name: _unit(rng) for name in "bc"}
    lengths = {"a": 0.32, "b": 0.21, "c": 0.40}

    def score(design: Design) -> float:
        own = _lengths(design)
        fit = math.exp(-sum((own[k] - lengths[k]) ** 2 for k in lengths) / 0.03)
        spec = fit * (0.4 + 0.6 * _alignment(design, axes))
        return 0.45 * tree_values[design.structure_index] + 0.55 * spec

    return score


def shifted_optima() -> Callable[[Design], float]:
    """8 trees, each with its own optimal lengths and axes near a shared one: what was
    learned on one tree is roughly, not exactly, right on another. The best tree is the
    star a-(b, c, d)."""
    rng = np.random.default_rng(606)
    tree_values = _tree_values(rng, len(LIMBS5_STRUCTURES), 0.1, 0.5, best=4)
    base_lengths = {name: float(rng.uniform(0.2, 0.4)) for name in "abcde"}
    base_axes = {name: _unit(rng) for name in "bcde"}
    per_tree = []
    for _ in LIMBS5_STRUCTURES:
        lengths = {k: v + float(rng.normal(0, 0.05)) for k, v in base_lengths.items()}
        axes = {}
        for name, axis in base_axes.items():
            tilted = axis + 0.4 * _unit(rng)
            axes[name] = tilted / np.linalg.norm(tilted)
        per_tree.append((lengths, axes))

    def score(design: Design) -> float:
        lengths, axes = per_tree[design.structure_index]
        own = _lengths(design)
        fit = math.exp(-sum((own[k] - lengths[k]) ** 2 for k in own) / (0.02 * len(own)))
        spec = fit * (0.3 + 0.7 * _alignment(design, axes))
        return 0.4 * tree_values[design.structure_index] + 0.6 * spec

    return score


def all_trees_space(names: str, radius: bool) -> dict[str, Any]:
    link: dict[str, Any] = {"length": {"low": 0.1, "high": 0.5}, "radius": 0.04, "mass": 1.0}
    if radius:
        link["radius"] = {"low": 0.02, "high": 0.08}
    return {
        "type": "design",
        "parts": {"link": link},
        "instances": [{"name": name, "part": "link"} for name in names],
        "structures": "all",
    }


def _edge_sets(space: dict[str, Any]) -> list[set[tuple[str, str]]]:
    space = {**space, "max_structures": 1000}
    return [set(edges) for edges in DesignSpace.model_validate(space).tree_structures()]


def needle_16() -> Callable[[Design], float]:
    """Every tree of 4 links (16): one tree far better than the rest, unrelated to how
    alike the trees are; lengths, radii and axes add half the score on any tree."""
    rng = np.random.default_rng(707)
    tree_values = _tree_values(rng, 16, 0.0, 0.4)
    radii = {name: float(rng.uniform(0.03, 0.07)) for name in "abcd"}
    lengths = {name: float(rng.uniform(0.15, 0.45)) for name in "abcd"}
    axes = {name: _unit(rng) for name in "bcd"}

    def score(design: Design) -> float:
        misfit = sum((link.length - lengths[link.name]) ** 2 for link in design.links) / 0.05
        misfit += sum((link.radius - radii[link.name]) ** 2 for link in design.links) / 0.002
        spec = math.exp(-misfit) * (0.3 + 0.7 * _alignment(design, axes))
        return 0.5 * tree_values[design.structure_index] + 0.5 * spec

    return score


def _depth(edges: set[tuple[str, str]], root: str) -> int:
    children: dict[str, list[str]] = {}
    for parent, child in edges:
        children.setdefault(parent, []).append(child)

    def down(node: str) -> int:
        return 1 + max((down(c) for c in children.get(node, [])), default=0)

    return down(root)


def tree_shape_64() -> tuple[Callable[[Design], float], list[list[tuple[str, str]]]]:
    """64 of the 125 trees of 5 links: the tree's value follows its shape (depth,
    leaves, the root's degree), so alike trees score alike but the best shape is one
    tree of few; lengths every tree has and the axes add 55%."""
    rng = np.random.default_rng(808)
    edge_sets = _edge_sets(all_trees_space("abcde", radius=False))
    depth_target, leaves_target = 4, 2
    axes = {name: _unit(rng) for name in "bcde"}
    lengths = {name: float(rng.uniform(0.15, 0.45)) for name in "abcde"}
    values = []
    for edges in edge_sets:
        parents = {p for p, _ in edges}
        leaves = len({c for _, c in edges} - parents)
        root_degree = sum(1 for p, _ in edges if p == "a")
        value = math.exp(-((_depth(edges, "a") - 1 - depth_target) ** 2) / 2.0)
        value *= math.exp(-((leaves - leaves_target) ** 2) / 2.0) * (0.8 + 0.2 * (root_degree == 1))
        values.append(value)
    order = rng.permutation(len(edge_sets))
    best = int(np.argmax(values))
    chosen = [best, *[int(i) for i in order if int(i) != best][:63]]
    chosen.sort()
    tree_values = np.array([values[i] for i in chosen])
    tree_values /= tree_values.max()

    def score(design: Design) -> float:
        own = _lengths(design)
        fit = math.exp(-sum((own[k] - lengths[k]) ** 2 for k in own) / 0.1)
        spec = fit * (0.3 + 0.7 * _alignment(design, axes))
        return 0.45 * tree_values[design.structure_index] + 0.55 * spec

    return score, [sorted(edge_sets[i], key=lambda e: (e[0], e[1])) for i in chosen]


def tree_shape_space(structures: list[list[tuple[str, str]]]) -> dict[str, Any]:
    space = all_trees_space("abcde", radius=False)
    space["structures"] = [[list(edge) for edge in edges] for edges in structures]
    return space


@dataclass(frozen=True)
class Objective:
    name: str
    space: dict[str, Any]
    score: Callable[[Design], float]


OBJECTIVES = {
    "tree-similarity": Objective("tree-similarity", limbs5_space(), tree_similarity()),
    "specs-only": Objective("specs-only", limbs5_space(), specs_only()),
    "unused-specs": Objective("unused-specs", limbs5_space(), unused_specs()),
    "interaction": Objective("interaction", arms4_space(), interaction()),
    "additive-trap": Objective("additive-trap", limbs5_space(), additive_trap()),
    "shifted-optima": Objective("shifted-optima", limbs5_space(), shifted_optima()),
    "needle-16": Objective("needle-16", all_trees_space("abcd", radius=True), needle_16()),
}
_SHAPE_SCORE, _SHAPE_TREES = tree_shape_64()
OBJECTIVES["tree-shape-64"] = Objective(
    "tree-shape-64", tree_shape_space(_SHAPE_TREES), _SHAPE_SCORE
)
EIGHT_TREES = {
    name
    for name, o in OBJECTIVES.items()
    if o.space is not None and o.space.get("structures") == LIMBS5_STRUCTURES
}
"""The objectives on the 8-tree, 13-spec space (issue 26's latency goal)."""
SERVICE_METHODS = {"qei": None, "qei-fused": "fused", "qei-onehot": "onehot"}
OPTUNA_METHODS = ("gp-optuna", "tpe-optuna", "random-optuna")
DEFAULT_METHODS = ["qei", "gp-optuna", "tpe-optuna", "random-optuna", "qei-onehot"]


def design_from_params(space: DesignSpace, params: dict[str, Any]) -> Design:
    """The design a trial's readable params (``design_params``) or Optuna params name."""
    layout = spec_layout(space)
    values = {key: float(params[key]) for key in layout.names if key in params}
    return build_design(space, layout, int(params["structure_index"]), values)


def run_service(http: httpx.Client, objective: Objective, method: str, seed: int) -> dict:
    space = dict(objective.space)
    encoding = SERVICE_METHODS[method]
    if encoding is not None:
        space["encoding"] = encoding
    parsed = DesignSpace.model_validate(space)
    created = http.post(
        "/api/v1/studies",
        json={
            "name": f"{objective.name}-{method}-{seed}-{time.time_ns()}",
            "direction": "maximize",
            "space": space,
            "proposer": {"name": "qei", "seed": seed},
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
    if not path.exists():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def best_by(values: list[float], n: int) -> float:
    return float(max(values[:n]))


def mann_whitney(a: list[float], b: list[float]) -> float:
    from scipy.stats import mannwhitneyu

    if len(a) < 2 or len(b) < 2 or (len(set(a)) == 1 and set(a) == set(b)):
        return 1.0
    return float(mannwhitneyu(a, b, alternative="two-sided").pvalue)


def report(records: list[dict]) -> str:
    """Per objective and method: the median and lower quartile of the best score by
    ``BUDGET``, the median number of trees a run tried, and the issue-26 goals (qei's
    median at or above GPSampler's, its lower quartile at or above random search's)."""
    methods = [m for m in DEFAULT_METHODS if any(r["method"] == m for r in records)]
    lines = [
        f"Best score by {BUDGET} evaluations over seeds: median / lower quartile "
        "(trees tried, median), n seeds. Goals (issue 26): qei's median at or above "
        "GPSampler's, qei's lower quartile at or above random search's.",
        "",
        "| objective | " + " | ".join(methods) + " | median vs GP | q1 vs random |",
        "| --- | " + " | ".join("---" for _ in methods) + " | --- | --- |",
    ]
    for name in OBJECTIVES:
        rows = {
            m: [r for r in records if r["objective"] == name and r["method"] == m] for m in methods
        }
        if not rows.get("qei"):
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
        verdict_gp = "-" if gp is None else ("met" if medians["qei"] >= gp else "**missed**")
        verdict_random = (
            "-" if random is None else ("met" if quartiles["qei"] >= random else "**missed**")
        )
        if gp is not None:
            p = mann_whitney(
                [best_by(r["values"], BUDGET) for r in rows["qei"]],
                [best_by(r["values"], BUDGET) for r in rows["gp-optuna"]],
            )
            verdict_gp += f" (p = {p:.2f})"
        lines.append(f"| {name} | " + " | ".join(cells) + f" | {verdict_gp} | {verdict_random} |")
    ask = {
        m: np.median([s for r in records if r["method"] == m for s in r["ask_seconds"]])
        for m in methods
    }
    late = {
        m: np.median(
            [
                s
                for r in records
                if r["method"] == m and r["objective"] in EIGHT_TREES
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
        + " (goal: qei under 0.5 s).",
    ]
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--objectives", nargs="+", default=list(OBJECTIVES))
    parser.add_argument("--methods", nargs="+", default=DEFAULT_METHODS)
    parser.add_argument("--results", type=Path, default=RESULTS_PATH, help="JSON lines, resumed")
    parser.add_argument("--no-write", action="store_true")
    parser.add_argument("--report", action="store_true", help="only rewrite the report")
    args = parser.parse_args()
    warnings.filterwarnings("ignore")
    if not args.report:
        done = {(r["objective"], r["method"], r["seed"]) for r in read_results(args.results)}
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
                        objective = OBJECTIVES[name]
                        started = time.perf_counter()
                        if method in SERVICE_METHODS:
                            result = run_service(http, objective, method, seed)
                        else:
                            result = run_optuna(objective, method, seed)
                        record = {"objective": name, "method": method, "seed": seed, **result}
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
    text = report(read_results(args.results))
    print(text)
    if not args.no_write:
        write_subsection("### Design-space suite, issue 26 (bench/design_suite.py)", text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
