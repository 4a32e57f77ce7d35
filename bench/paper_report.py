"""Plots, pictures and documents from bench/paper.py's results (``paper.py --report``);
the numbers are bench/paper_stats.py's."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np

from bench.paper_stats import (
    EARLY,
    Study,
    fusion_comparison,
    goals,
    grouped,
    load,
    ordered_keys,
    ranking_agreement,
    sensitivity,
    table,
)
from bench.paperlib import (
    BASELINE_BUDGET,
    DEFAULT_SEEDS,
    MODEL_BUDGET,
    QUICK,
    REPO,
    RESULTS,
    RL_SEEDS,
    TASK_LABELS,
    TASKS,
    read_jsonl,
)

DOCS = REPO / "docs"
FIGURES = DOCS / "paper"
PAPER_MD = DOCS / "paper.md"
RESULTS_MD = REPO / "bench" / "RESULTS.md"
SECTION = "## Paper Table 1 (issue 7)"
START, END = "<!-- paper.py:generated:start -->", "<!-- paper.py:generated:end -->"
COLOURS = {
    "qei": "tab:blue",
    "nelder-mead": "tab:red",
    "tpe": "tab:green",
    "random": "tab:gray",
    "qei-onehot": "tab:purple",
    "qei-b30": "tab:cyan",
    "qei-mixed": "tab:orange",
}
EXTRA_COLOURS = ["tab:olive", "tab:brown", "tab:pink", "black"]
"""For other tagged measurements (dotted lines), in order of appearance."""


# -- figures ---------------------------------------------------------------------------


def plot_best_so_far(
    studies: list[Study], best_known: dict[str, Any], learner: str, folder: Path
) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = []
    groups = grouped(studies)
    for task in TASKS:
        keys = [k for k in ordered_keys(groups) if k[0] == task]
        if not keys:
            continue
        figure, axes = plt.subplots(figsize=(6.4, 4.0), dpi=110)
        length = max(s.budget for k in keys for s in groups[k])
        x = np.arange(1, length + 1)
        extras = iter(EXTRA_COLOURS * 4)
        for key in keys:
            curves = np.array([s.best_so_far(length) for s in groups[key]])
            with np.errstate(all="ignore"):
                import warnings

                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", RuntimeWarning)
                    median = np.nanmedian(curves, axis=0)
                    low = np.nanpercentile(curves, 25, axis=0)
                    high = np.nanpercentile(curves, 75, axis=0)
            budget = max(s.budget for s in groups[key])
            colour = COLOURS.get(key[1]) or next(extras)
            style = "--" if key[1].endswith("onehot") else "-" if key[1] in COLOURS else ":"
            axes.plot(
                x[:budget],
                median[:budget],
                color=colour,
                label=f"{key[1]} (n={len(groups[key])})",
                linestyle=style,
            )
            axes.fill_between(x[:budget], low[:budget], high[:budget], color=colour, alpha=0.15)
        entry = best_known.get(task, {}).get(learner)
        if entry:
            axes.axhline(entry["target"], color="black", linewidth=0.8, linestyle=":")
            axes.annotate(
                f"target {entry['target']:.3f} (95% of best known)",
                (1, entry["target"]),
                textcoords="offset points",
                xytext=(2, 3),
                fontsize=8,
            )
        axes.axvline(EARLY, color="black", linewidth=0.5, alpha=0.4)
        axes.set_xlabel("evaluations")
        axes.set_ylabel("best score so far")
        axes.set_title(f"{TASK_LABELS[task]}, {learner}: median, IQR over seeds", fontsize=10)
        axes.legend(fontsize=8, loc="lower right")
        axes.grid(alpha=0.3)
        figure.tight_layout()
        path = folder / f"bestsofar-{task}-{learner}.png"
        figure.savefig(path)
        plt.close(figure)
        paths.append(path)
    return paths


PICTURE_LABEL = "activedesign-best"
"""A best-design picture's PNG text key: which study's design it shows."""


def best_designs(studies: list[Study], learner: str, folder: Path) -> list[str]:
    """Copy each (task, method)'s best design picture, labelled with the study and
    evaluation it shows; return markdown table rows. Once the run's own picture is gone
    the copy stands in, but only while it shows the design the row names."""
    groups = grouped(studies)
    rows = []
    for key in ordered_keys(groups):
        candidates = [s for s in groups[key] if s.record.get("best") and s.record.get("png")]
        if not candidates:
            continue
        study = max(candidates, key=lambda s: s.record["best"]["value"])
        best = study.record["best"]
        label = f"{key[0]} {key[1]} {learner} seed {study.record['seed']} number {best['number']}"
        source = REPO / study.record["png"]
        copy = folder / f"best-{key[0]}-{key[1]}-{learner}.png"
        if source.exists():
            save_labelled(source, copy, label)
        elif picture_label(copy) != label:
            continue
        rows.append(
            f"| {TASK_LABELS[key[0]]} | {key[1]} | ![{key[1]}](paper/{copy.name}) "
            f"| {best['value']:.4f} (seed {study.record['seed']}, evaluation "
            f"{best['number'] + 1}) | {_design_text(best['params'])} |"
        )
    return rows


def save_labelled(source: Path, copy: Path, label: str) -> None:
    """``source`` saved as ``copy``, a PNG whose ``PICTURE_LABEL`` text is ``label``."""
    from PIL import Image, PngImagePlugin

    info = PngImagePlugin.PngInfo()
    info.add_text(PICTURE_LABEL, label)
    with Image.open(source) as image:
        image.save(copy, format="PNG", pnginfo=info)


def picture_label(path: Path) -> str | None:
    """The ``PICTURE_LABEL`` of a picture saved by :func:`save_labelled` (None: no such
    file, or a picture without one)."""
    if not path.exists():
        return None
    from PIL import Image

    with Image.open(path) as image:
        return getattr(image, "text", {}).get(PICTURE_LABEL)


def _design_text(params: dict[str, Any]) -> str:
    parts = [f"tree {params.get('structure', '?')}"]
    for key, value in params.items():
        if key.endswith(".joint.axis") and isinstance(value, list):
            parts.append(f"{key.split('.')[0]} axis ({', '.join(f'{v:.2f}' for v in value)})")
        elif key.endswith(".length") and isinstance(value, float):
            parts.append(f"{key} {value:.2f}")
    return "; ".join(parts)


# -- documents -------------------------------------------------------------------------


def best_known_lines(best_known: dict[str, Any], dense: dict[str, list[float]]) -> list[str]:
    """``dense``: the fast-learner scores of each task's dense Sobol designs."""
    lines = [
        "| task | learner | best known (mean over seeds) | target (95%) "
        "| dense Sobol designs: median / best single | dense designs reaching the target "
        "(fast) | best design |",
        "| --- | --- | ---: | ---: | ---: | ---: | --- |",
    ]
    for task, entry in best_known.items():
        for learner in ("fast", "ddpg"):
            if learner not in entry:
                continue
            e = entry[learner]
            seeds = ", ".join(f"{v:.3f}" for v in e["seed_scores"])
            values = dense.get(task, [])
            reached = (
                f"{sum(v >= e['target'] for v in values)}/{len(values)}"
                if learner == "fast" and values
                else "-"
            )
            lines.append(
                f"| {TASK_LABELS.get(task, task)} | {learner} | {e['score']:.4f} ({seeds}) "
                f"| {e['target']:.4f} | {entry['dense_median']:.4f} / "
                f"{entry['dense_best_single']:.4f} | {reached} | {e['design_id']}: "
                f"{_design_text(e['params'])} |"
            )
    return lines


def dense_scores(quick: bool) -> dict[str, list[float]]:
    path = (QUICK if quick else RESULTS) / "best_known_evals.jsonl"
    out: dict[str, list[float]] = {}
    for record in read_jsonl(path):
        if record.get("stage") == "dense":
            out.setdefault(record["task"], []).append(record["value"])
    return out


def generated_block(
    best_known: dict[str, Any], studies: dict[str, list[Study]], quick: bool, folder: Path
) -> tuple[list[str], list[str]]:
    """(lines for docs/paper.md, lines for bench/RESULTS.md)."""
    doc: list[str] = []
    summary: list[str] = []
    codes = sorted({s.record.get("code", "?") for group in studies.values() for s in group})
    doc.append(f"Code under test: {', '.join(codes) or '-'} (`bench/results/code_ref`).")
    doc.append("")
    doc.append("### Best-known scores and targets")
    doc.append("")
    doc.extend(best_known_lines(best_known, dense_scores(quick)))
    doc.append("")
    for learner in sorted(studies, key=lambda k: (k != "fast", k)):
        group = studies[learner]
        label = "fast learner" if learner == "fast" else f"{learner} learner (RL)"
        rows = table(group, best_known, learner)
        goal_lines = goals(group, learner)
        doc += [f"### Table 1, {label}", "", *rows, "", "Goals:", "", *goal_lines, ""]
        doc += [
            f"Evaluations to other fractions of the best-known score, {label} (a "
            "sensitivity check; the goals are judged at 95% only):",
            "",
            *sensitivity(group, best_known, learner),
            "",
        ]
        summary += [f"Table 1, {label}:", "", *rows, "", *goal_lines, ""]
        plots = plot_best_so_far(group, best_known, learner, folder)
        doc += [f"Best score so far, {label} (median line, interquartile band):", ""]
        doc += [f"![{p.stem}](paper/{p.name})" for p in plots]
        doc.append("")
        fusion = fusion_comparison(group)
        if fusion:
            doc += [f"### Fused vs plain (one-hot) encoding, {label}", "", *fusion, ""]
            summary += [f"Fused vs one-hot encoding, {label}:", "", *fusion, ""]
        pictures = best_designs(group, learner, folder)
        if pictures:
            doc += [
                f"### Best design found per method, {label}",
                "",
                "| task | method | picture (final pose) | score | design |",
                "| --- | --- | --- | ---: | --- |",
                *pictures,
                "",
            ]
    for other in sorted(k for k in studies if k != "fast"):
        if "fast" not in studies:
            break
        agreement = ranking_agreement(studies, best_known, other)
        text = (
            f"Ranking of the methods, fast learner vs {other}: median best score within 15 "
            "evaluations relative to that learner's best known (a measure every study has, "
            "censored or not; ties in a task's ranking make tau smaller):"
        )
        doc += [f"### Ranking agreement, fast vs {other}", "", text, "", *agreement, ""]
        summary += [text, "", *agreement, ""]
    if quick:
        doc.insert(0, "**Quick (smoke) run: 1 seed, 5 evaluations; not results.**\n")
    return doc, summary


def _replace_block(text: str, block: list[str]) -> str:
    body = "\n".join([START, *block, END])
    if START in text and END in text:
        return re.sub(re.escape(START) + ".*?" + re.escape(END), lambda _: body, text, flags=re.S)
    return text.rstrip() + "\n\n" + body + "\n"


def write_results_section(summary: list[str]) -> None:
    text = RESULTS_MD.read_text() if RESULTS_MD.exists() else "# Benchmark results\n"
    intro = (
        "Command: `.venv/bin/python bench/best_known.py && .venv/bin/python bench/paper.py` "
        "(fast learner, resumable), then `.venv/bin/python bench/paper.py --learner ddpg` "
        "(RL, 3 seeds). Full write-up, plots and design pictures: [docs/paper.md]"
        "(../docs/paper.md)."
    )
    if SECTION not in text:
        text = text.rstrip() + f"\n\n{SECTION}\n\n{intro}\n\n{START}\n{END}\n"
    head, _, rest = text.partition(SECTION)
    following = re.search(r"^## ", rest, flags=re.M)
    section, tail = (
        (rest[: following.start()], rest[following.start() :])
        if following
        else (
            rest,
            "",
        )
    )
    section = _replace_block(section, summary)
    RESULTS_MD.write_text(head + SECTION + section.rstrip() + "\n" + ("\n" + tail if tail else ""))


DOC_HEAD = """# Paper Table 1: evaluations to a good robot design

This page is written by `bench/paper.py --report` between the markers below; the
notes outside them are written by hand. See `bench/paper.py` and
`bench/best_known.py` for exactly what runs.
"""


def write_report(console: Any, *, quick: bool) -> None:
    best_known, studies = load(quick)
    if not studies:
        console.print("no results yet")
        return
    folder = QUICK / "figures" if quick else FIGURES
    folder.mkdir(parents=True, exist_ok=True)
    doc, summary = generated_block(best_known, studies, quick, folder)
    if quick:
        from rich.markdown import Markdown

        console.print(Markdown("\n".join(summary)))
        estimate(console, studies)
        return
    text = PAPER_MD.read_text() if PAPER_MD.exists() else DOC_HEAD
    PAPER_MD.write_text(_replace_block(text, doc))
    write_results_section(summary)
    console.print(f"wrote {PAPER_MD.relative_to(REPO)}, {RESULTS_MD.relative_to(REPO)}")
    for line in summary:
        console.print(line, markup=False, highlight=False)


def estimate(console: Any, studies: dict[str, list[Study]]) -> None:
    """From a quick run: seconds per evaluation by (task, method), scaled to the full grid."""
    for learner, group in studies.items():
        seeds = DEFAULT_SEEDS.get(learner, RL_SEEDS)
        total = 0.0
        for (_task, method), members in grouped(group).items():
            per_eval = np.mean([s.record["wall_s"] / s.budget for s in members])
            budget = MODEL_BUDGET if method.startswith("qei") else BASELINE_BUDGET
            total += per_eval * budget * seeds
        console.print(
            f"estimated full {learner} grid ({seeds} seeds, budgets {MODEL_BUDGET}/"
            f"{BASELINE_BUDGET}): {total / 3600:.1f} h at this run's load"
        )
