"""The numbers of bench/paper.py's results: its studies, tables and goals (the report,
bench/paper_report.py, draws and writes them).

Definitions (also printed in docs/paper.md):
- evaluations to target: 1 + the number of the first trial (in proposal order) whose
  score reaches the target, 95% of the task's best-known score for the study's
  learner (bench/best_known.py); a study that never reaches it within its budget is
  censored (counted as "more than the budget": medians and quartiles that fall on
  censored studies print as ">B").
- success within 15 / within budget: the fraction of seeds reaching the target by
  evaluation 15 / by the study's last evaluation.
- wall time per study: from the create request until every trial of the budget is
  scored, measured by the bench client (two workers, two cores shared with whatever
  else ran: the load average is recorded); time to target: from the study's creation
  to the end of the first trial that reached the target (server clock).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bench.paperlib import (
    BEST_KNOWN,
    QUICK,
    RESULTS,
    TARGET_FRACTION,
    TASK_LABELS,
    TASKS,
    quantiles,
    read_jsonl,
)

METHOD_ORDER = ["qei-mixed", "qei", "qei-b30", "nelder-mead", "tpe", "random", "qei-onehot"]
GOAL_MEDIAN = {"stand-up": 5, "diagonal-gesture": 7}
EARLY = 15


@dataclass
class Study:
    record: dict[str, Any]
    target: float | None
    values: list[float | None] = field(default_factory=list)

    def __post_init__(self) -> None:
        trials = sorted(self.record["trials"], key=lambda t: t["number"])
        self.values = [t["value"] if t["state"] == "complete" else None for t in trials]
        self.trials = trials

    @property
    def budget(self) -> int:
        return int(self.record["budget"])

    @property
    def evals_to_target(self) -> float:
        return self.evals_to(self.target)

    def evals_to(self, target: float | None) -> float:
        """1 + the number of the first trial scoring at least ``target``; inf if none."""
        if target is None:
            return math.nan
        for index, value in enumerate(self.values):
            if value is not None and value >= target:
                return float(index + 1)
        return math.inf

    @property
    def time_to_target(self) -> float:
        count = self.evals_to_target
        if not math.isfinite(count):
            return math.nan
        finished = self.trials[int(count) - 1]["finished_s"]
        return float(finished) if finished is not None else math.nan

    def best_so_far(self, length: int) -> np.ndarray:
        out = np.full(length, np.nan)
        best = -np.inf
        for index in range(min(length, len(self.values))):
            value = self.values[index]
            if value is not None:
                best = max(best, value)
            out[index] = best if np.isfinite(best) else np.nan
        return out

    def best_within(self, count: int) -> float:
        values = [v for v in self.values[:count] if v is not None]
        return max(values) if values else math.nan

    @property
    def worker_s(self) -> float:
        return float(sum(t["worker_s"] or 0.0 for t in self.trials))

    @property
    def ask_s(self) -> float:
        return float(sum(t.get("ask_s") or 0.0 for t in self.trials))


def load(quick: bool) -> tuple[dict[str, Any], dict[str, list[Study]]]:
    """Best-known scores and the studies, by learner."""
    folder = QUICK if quick else RESULTS
    best_path = folder / "best_known.json" if quick else BEST_KNOWN
    if quick and not best_path.exists():
        best_path = BEST_KNOWN
    best_known = json.loads(best_path.read_text())["tasks"] if best_path.exists() else {}
    studies: dict[str, list[Study]] = {}
    for path in sorted(folder.glob("paper-*.jsonl")):
        for record in read_jsonl(path):
            if record.get("tag"):  # an extra measurement: its own row
                record["method"] = f"{record['method']}-{record['tag']}"
            entry = best_known.get(record["task"], {}).get(record["learner"])
            target = entry["target"] if entry else None
            studies.setdefault(record["learner"], []).append(Study(record, target))
    return best_known, studies


# -- numbers ---------------------------------------------------------------------------


def _count(value: float, budget: int | None = None) -> str:
    if math.isnan(value):
        return "-"
    if math.isinf(value):
        return f">{budget}" if budget else "inf"
    return f"{value:g}" if value == int(value) else f"{value:.1f}"


def summarise(group: list[Study]) -> dict[str, Any]:
    budget = max(s.budget for s in group)
    counts = [s.evals_to_target for s in group]
    q1, median, q3 = quantiles(counts)
    reached = [s for s in group if math.isfinite(s.evals_to_target)]
    times = [s.time_to_target for s in reached if not math.isnan(s.time_to_target)]
    return {
        "n": len(group),
        "budget": budget,
        "median": median,
        "q1": q1,
        "q3": q3,
        "early": sum(1 for c in counts if c <= EARLY),
        "within": len(reached),
        "wall": float(np.median([s.record["wall_s"] for s in group])),
        "wall_q": quantiles([s.record["wall_s"] for s in group], (0.25, 0.75)),
        "time_to_target": float(np.median(times)) if times else math.nan,
        "best_early": float(np.nanmedian([s.best_within(EARLY) for s in group])),
        "worker_s": float(np.median([s.worker_s for s in group])),
        "ask_s": float(np.median([s.ask_s for s in group])),
        "load": float(np.median([s.record.get("load_before", math.nan) for s in group])),
    }


def grouped(studies: list[Study]) -> dict[tuple[str, str], list[Study]]:
    groups: dict[tuple[str, str], list[Study]] = {}
    for study in studies:
        groups.setdefault((study.record["task"], study.record["method"]), []).append(study)
    return groups


def ordered_keys(groups: dict[tuple[str, str], list[Study]]) -> list[tuple[str, str]]:
    tasks = list(TASKS)
    return sorted(
        groups,
        key=lambda k: (
            tasks.index(k[0]) if k[0] in tasks else 99,
            METHOD_ORDER.index(k[1]) if k[1] in METHOD_ORDER else 99,
        ),
    )


def table(studies: list[Study], best_known: dict[str, Any], learner: str) -> list[str]:
    groups = grouped(studies)
    lines = [
        "| task | method | seeds | budget | evaluations to target: median [IQR] "
        "| reached within 15 | within budget | wall s / study: median [IQR] "
        "| time to target s: median | best score by 15 / best known: median "
        "| worker s / study | proposer s / study |",
        "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for key in ordered_keys(groups):
        task, method = key
        s = summarise(groups[key])
        entry = best_known.get(task, {}).get(learner)
        ratio = s["best_early"] / entry["score"] if entry and entry["score"] else math.nan
        b = s["budget"]
        lines.append(
            f"| {TASK_LABELS.get(task, task)} | {method} | {s['n']} | {b} "
            f"| {_count(s['median'], b)} [{_count(s['q1'], b)}, {_count(s['q3'], b)}] "
            f"| {s['early']}/{s['n']} | {s['within']}/{s['n']} "
            f"| {s['wall']:.0f} [{s['wall_q'][0]:.0f}, {s['wall_q'][1]:.0f}] "
            f"| {_fmt(s['time_to_target'], '.0f')} | {_fmt(ratio, '.3f')} "
            f"| {s['worker_s']:.0f} | {s['ask_s']:.1f} |"
        )
    return lines


def _fmt(value: float, spec: str) -> str:
    return "-" if value is None or math.isnan(value) else format(value, spec)


def goals(studies: list[Study], learner: str) -> list[str]:
    """The issue's goals, judged on these numbers (never tuned: see docs/paper.md)."""
    groups = grouped(studies)
    lines = []
    for task, limit in GOAL_MEDIAN.items():
        qei = groups.get((task, "qei"))
        if not qei:
            continue
        s = summarise(qei)
        ok = s["median"] <= limit
        by = (
            ""
            if ok
            else f" by {_count(s['median'] - limit)}"
            if math.isfinite(s["median"])
            else " (more than half the seeds do not reach it within the budget)"
        )
        lines.append(
            f"- {task}, qei median evaluations to target {_count(s['median'], s['budget'])} "
            f"(goal <= {limit}): {'met' if ok else 'missed'}{by}"
        )
        ok = s["early"] >= math.ceil(0.9 * s["n"])
        lines.append(
            f"- {task}, qei seeds reaching the target within 15: {s['early']}/{s['n']} "
            f"(goal >= 9/10 of the seeds): {'met' if ok else 'missed'}"
        )
        longer = groups.get((task, "qei-b30"))
        for method, factor in (("nelder-mead", 3), ("tpe", 2), ("random", 2)):
            other = groups.get((task, method))
            if not other:
                continue
            o = summarise(other)
            lines.append(f"- {task}, {method} vs qei: " + _ratio(o, s, factor))
            if longer:
                lines.append(
                    f"- {task}, {method} vs qei given 30 evaluations (qei-b30): "
                    + _ratio(o, summarise(longer), factor)
                )
    lines += default_goals(groups)
    for task in TASKS:
        qei = groups.get((task, "qei"))
        if qei and task == "stand-up":
            s = summarise(qei)
            lines.append(
                f"- {task}, qei wall time per full study ({s['budget']} evaluations, 2 workers): "
                f"median {s['wall']:.0f} s, time to target median "
                f"{_fmt(s['time_to_target'], '.0f')} s (goal < 120 s): "
                + ("met" if s["wall"] < 120 else "missed")
                + f" (load average at start, median {s['load']:.1f} on 2 cores)"
            )
    return lines


def default_goals(groups: dict[tuple[str, str], list[Study]]) -> list[str]:
    """Issue 12's goals for today's default (qei-mixed): stand-up within 15 in at least
    8/10 seeds (moonshot: median 5), and on lift-highest a better best score by 15 than
    both the preprint's fused encoding and one-hot (two-sided Mann-Whitney U)."""
    from scipy.stats import mannwhitneyu

    lines = []
    standup = groups.get(("stand-up", "qei-mixed"))
    if standup:
        s = summarise(standup)
        ok = s["early"] >= math.ceil(0.8 * s["n"])
        lines.append(
            f"- stand-up, qei-mixed seeds reaching the target within 15: {s['early']}/{s['n']} "
            f"(goal >= 8/10): {'met' if ok else 'missed'}; median evaluations "
            f"{_count(s['median'], s['budget'])} (moonshot <= 5: "
            f"{'met' if s['median'] <= 5 else 'missed'})"
        )
    mixed = groups.get(("lift-highest", "qei-mixed"))
    for other, label in (("qei", "the fused encoding (qei)"), ("qei-onehot", "one-hot")):
        group = groups.get(("lift-highest", other))
        if not mixed or not group:
            continue
        ours = [s.best_within(EARLY) for s in mixed]
        theirs = [s.best_within(EARLY) for s in group]
        p = mannwhitneyu(ours, theirs, alternative="two-sided").pvalue
        above = np.median(ours) > np.median(theirs)
        lines.append(
            f"- lift-highest, qei-mixed vs {label}, median best by 15: {np.median(ours):.4f} "
            f"vs {np.median(theirs):.4f} (two-sided Mann-Whitney U p = {p:.3f}): "
            + ("above" if above else "**not above**")
        )
    return lines


def _ratio(other: dict[str, Any], qei: dict[str, Any], factor: int) -> str:
    """'other needs >= factor x qei's evaluations' on medians; censored medians give bounds."""
    if math.isinf(qei["median"]):
        return f"qei's median is censored (>{qei['budget']}): no ratio"
    if qei["median"] <= 0 or math.isnan(qei["median"]):
        return "no ratio"
    if math.isinf(other["median"]):
        bound = (other["budget"] + 1) / qei["median"]
        verdict = "met" if bound >= factor else "undecided (its budget is too short to tell)"
        return (
            f"median >{other['budget']} vs {_count(qei['median'])}: ratio > {bound:.1f} "
            f"(goal >= {factor}x): {verdict}"
        )
    ratio = other["median"] / qei["median"]
    verdict = "met" if ratio >= factor else f"missed (needs {factor}x)"
    return (
        f"median {_count(other['median'])} vs {_count(qei['median'])}: ratio {ratio:.1f} "
        f"(goal >= {factor}x): {verdict}"
    )


SENSITIVITY = (0.8, 0.9, TARGET_FRACTION)


def sensitivity(studies: list[Study], best_known: dict[str, Any], learner: str) -> list[str]:
    """Evaluations to other fractions of the best known: how the picture depends on the
    95% bar (the goals are judged at 95% only)."""
    groups = grouped(studies)
    header = " | ".join(f"{int(f * 100)}%: median (within 15)" for f in SENSITIVITY)
    lines = [
        f"| task | method | {header} |",
        "| --- | --- |" + " ---: |" * len(SENSITIVITY),
    ]
    for key in ordered_keys(groups):
        entry = best_known.get(key[0], {}).get(learner)
        if not entry:
            continue
        cells = []
        for fraction in SENSITIVITY:
            counts = [s.evals_to(fraction * entry["score"]) for s in groups[key]]
            budget = max(s.budget for s in groups[key])
            early = sum(1 for c in counts if c <= EARLY)
            cells.append(f"{_count(quantiles(counts, (0.5,))[0], budget)} ({early}/{len(counts)})")
        lines.append(f"| {TASK_LABELS[key[0]]} | {key[1]} | " + " | ".join(cells) + " |")
    return lines


def ranking(studies: list[Study], best_known: dict[str, Any], learner: str) -> dict[str, list]:
    """Per task, methods ordered by median best score within 15 evaluations (relative to
    the learner's best known): every method has a value there, censored or not."""
    out: dict[str, list] = {}
    for (task, method), group in grouped(studies).items():
        if method not in ("qei", "nelder-mead", "tpe", "random"):
            continue
        entry = best_known.get(task, {}).get(learner)
        if not entry:
            continue
        value = float(np.nanmedian([s.best_within(EARLY) for s in group])) / entry["score"]
        out.setdefault(task, []).append((method, value))
    return {task: sorted(rows, key=lambda r: -r[1]) for task, rows in out.items()}


def ranking_agreement(
    studies: dict[str, list[Study]], best_known: dict[str, Any], other: str
) -> list[str]:
    from scipy.stats import kendalltau

    fast = ranking(studies["fast"], best_known, "fast")
    rl = ranking(studies[other], best_known, other)
    lines = [
        f"| task | fast learner: best by 15 / best known | {other}: best by 15 / best known "
        "| Kendall tau |",
        "| --- | --- | --- | ---: |",
    ]
    for task in TASKS:
        if task not in fast or task not in rl:
            continue
        a, b = dict(fast[task]), dict(rl[task])
        common = [m for m in a if m in b]
        tau = kendalltau([a[m] for m in common], [b[m] for m in common]).statistic
        lines.append(
            f"| {TASK_LABELS[task]} | "
            + " > ".join(f"{m} {v:.3f}" for m, v in fast[task])
            + " | "
            + " > ".join(f"{m} {v:.3f}" for m, v in rl[task])
            + f" | {tau:.2f} |"
        )
    return lines


def fusion_comparison(studies: list[Study]) -> list[str]:
    """Fused (the default, then any tagged variant of its space options) vs one-hot."""
    groups = grouped(studies)
    lines = []
    for task in TASKS:
        fused, plain = groups.get((task, "qei")), groups.get((task, "qei-onehot"))
        if not fused or not plain:
            continue
        from scipy.stats import mannwhitneyu

        variants = [("fused (qei)", fused)]
        for (other_task, method), group in sorted(groups.items()):
            space = group[0].record.get("space")
            if other_task == task and group[0].record.get("encoding") == "fused" and space:
                options = ", ".join(f"{k}={v}" for k, v in sorted(space.items()))
                variants.append((f"fused, {options} ({method})", group))
        variants.append(("one-hot (qei)", plain))
        for label, group in variants:
            summary = summarise(group)
            best = [s.best_within(EARLY) for s in group]
            budget = summary["budget"]
            lines.append(
                f"| {TASK_LABELS[task]} | {label} | {summary['n']} "
                f"| {_count(summary['median'], budget)} [{_count(summary['q1'], budget)}, "
                f"{_count(summary['q3'], budget)}] | {summary['early']}/{summary['n']} "
                f"| {np.median(best):.4f} [{np.percentile(best, 25):.4f}, "
                f"{np.percentile(best, 75):.4f}] | {_structures(group)} |"
            )
        test = mannwhitneyu(
            [s.best_within(EARLY) for s in fused],
            [s.best_within(EARLY) for s in plain],
            alternative="two-sided",
        )
        lines.append(
            f"| | fused (qei) vs one-hot | | | | Mann-Whitney U on best by 15, two-sided: "
            f"p = {test.pvalue:.3f} | |"
        )
    if lines:
        lines = [
            "| task | encoding | seeds | evaluations to target: median [IQR] "
            "| reached within 15 | best score by 15: median [IQR] | structure of each best |",
            "| --- | --- | ---: | ---: | ---: | ---: | --- |",
            *lines,
        ]
    return lines


def _structures(group: list[Study]) -> str:
    counts: dict[str, int] = {}
    for study in group:
        structure = study.record.get("best", {}).get("params", {}).get("structure")
        if structure:
            counts[structure] = counts.get(structure, 0) + 1
    return "; ".join(f"{k} x{v}" for k, v in sorted(counts.items(), key=lambda kv: -kv[1]))
