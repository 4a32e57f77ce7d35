"""A benchmark against a baseline commit, same machine, same command: the only comparison
that tells a regression from a slower machine.

``compare.py --baseline REV -- SCRIPT ARGS...`` checks REV out into a temporary git
worktree (removed at the end, also on a failed run, Ctrl-C or SIGTERM) and runs SCRIPT
``--runs`` times against each tree, alternating (baseline, current, baseline, current,
...). A run against a tree has that tree's ``client``, ``service`` and ``workers`` first on
``PYTHONPATH`` (they win over the editable install, also in the ``adserver`` and
``adworker`` processes a script starts: those inherit the environment), so the baseline's
runs measure the baseline's code.

Both arms run the *current* SCRIPT: the same measurement, only the code measured differs.
Where that script cannot import against the baseline (an ``ImportError`` in the first
baseline run) and the baseline has its own copy of it, the baseline runs its own copy
instead, and the report says so.

A script reports its figures as lines ``BENCH {"metric": ..., "value": ...,
"higher_is_better": ..., "unit": ...}`` on its stdout (``adclient.testing.figures.emit``),
one per metric per run.
The report, per metric: the baseline's and the current tree's medians, the median of the
paired ratios current / baseline (run i of one arm with run i of the other) and their
range, the number of runs; the machine (CPU model, cores, load average) and both commits.
It is printed as a Markdown table, ready for bench/RESULTS.md. A run that exits non-zero
or prints no valid result line stops the comparison with its exit status and the last
lines it wrote (exit status 1).

    python bench/compare.py --baseline REV [--runs 5] [--markdown FILE] [--json FILE] \\
        -- SCRIPT [ARGS...]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import re
import shlex
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from adclient.testing.figures import PREFIX

CODE_DIRS = ("client", "service", "workers")
RUN_DIRS = (*CODE_DIRS, "bench", "tests")
IMPORT_FAILED = re.compile(r"^(ModuleNotFoundError|ImportError): ", re.MULTILINE)
TAIL_LINES = 30
STOP_GRACE_S = 30.0


@dataclass(frozen=True)
class Figure:
    metric: str
    value: float
    higher_is_better: bool
    unit: str


class RunFailed(Exception):
    """A run of the script that gave no figures: why, in words."""


def parse(stdout: str) -> dict[str, Figure]:
    """The figures of one run's ``BENCH`` lines, by metric."""
    figures: dict[str, Figure] = {}
    for line in stdout.splitlines():
        if not line.startswith(PREFIX):
            continue
        try:
            data = json.loads(line[len(PREFIX) :])
            figure = Figure(
                metric=data["metric"],
                value=data["value"],
                higher_is_better=data["higher_is_better"],
                unit=data.get("unit", ""),
            )
        except (ValueError, KeyError, TypeError) as error:
            raise RunFailed(f"a result line that does not parse ({error!r}): {line}") from None
        if (
            not isinstance(figure.metric, str)
            or isinstance(figure.value, bool)
            or not isinstance(figure.value, int | float)
            or not isinstance(figure.higher_is_better, bool)
            or not isinstance(figure.unit, str)
        ):
            raise RunFailed(f"a result line of the wrong types: {line}")
        if figure.metric in figures:
            raise RunFailed(f"metric {figure.metric!r} reported twice in one run")
        figures[figure.metric] = figure
    if not figures:
        raise RunFailed(f"no result line (a line starting {PREFIX.strip()!r}) on its stdout")
    return figures


@dataclass(frozen=True)
class Tree:
    """A checkout whose code a run measures."""

    label: str
    root: Path
    commit: str

    def pythonpath(self, script_root: Path) -> str:
        return os.pathsep.join([*(str(self.root / d) for d in CODE_DIRS), str(script_root)])


def git(*args: str, cwd: Path) -> str:
    done = subprocess.run(["git", *args], cwd=cwd, capture_output=True, text=True)
    if done.returncode != 0:
        raise RunFailed(f"git {' '.join(args)}: {done.stderr.strip()}")
    return done.stdout.strip()


def describe(root: Path, *, work_tree: bool = False) -> str:
    """Short commit and date; of a ``work_tree``, '+ uncommitted changes' where the code a
    run imports (RUN_DIRS) has them."""
    text = git("log", "-1", "--format=%h (%cs)", cwd=root)
    if work_tree and git(
        "status", "--porcelain", "--untracked-files=no", "--", *RUN_DIRS, cwd=root
    ):
        text += " + uncommitted changes"
    return text


@contextlib.contextmanager
def baseline_worktree(repo: Path, rev: str) -> Iterator[Path]:
    """A detached worktree of ``rev`` in a fresh temporary folder, gone afterwards."""
    temp = Path(tempfile.mkdtemp(prefix="ad-compare-"))
    path = temp / "baseline"
    try:
        git("worktree", "add", "--detach", str(path), rev, cwd=repo)
        yield path
    finally:
        subprocess.run(
            ["git", "worktree", "remove", "--force", str(path)], cwd=repo, capture_output=True
        )
        subprocess.run(["git", "worktree", "prune"], cwd=repo, capture_output=True)
        shutil.rmtree(temp, ignore_errors=True)


def stop_group(process: subprocess.Popen[str]) -> None:
    """Interrupt a run's process group (the script stops its servers), then kill what is left."""
    with contextlib.suppress(ProcessLookupError):
        os.killpg(process.pid, signal.SIGINT)
    with contextlib.suppress(subprocess.TimeoutExpired):
        process.wait(timeout=STOP_GRACE_S)
    with contextlib.suppress(ProcessLookupError):
        os.killpg(process.pid, signal.SIGKILL)
    process.wait()


@dataclass
class Outcome:
    returncode: int
    stdout: str
    stderr: str
    seconds: float

    def tail(self) -> str:
        lines = (self.stdout + self.stderr).splitlines()[-TAIL_LINES:]
        return "\n".join(f"    {line}" for line in lines)


def run_script(command: list[str], pythonpath: str) -> Outcome:
    """One run in a process group of its own, so that an abort reaches its servers too."""
    env = {**os.environ, "PYTHONPATH": pythonpath}
    started = time.perf_counter()
    process = subprocess.Popen(
        command,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    try:
        stdout, stderr = process.communicate()
    except BaseException:
        stop_group(process)
        raise
    return Outcome(process.returncode, stdout, stderr, time.perf_counter() - started)


@dataclass
class Arm:
    tree: Tree
    script: Path
    script_root: Path
    runs: list[dict[str, Figure]] = field(default_factory=list)

    def run(self, args: list[str]) -> Outcome:
        command = [sys.executable, str(self.script), *args]
        return run_script(command, self.tree.pythonpath(self.script_root))


@dataclass
class Summary:
    metric: str
    unit: str
    higher_is_better: bool
    baseline: list[float]
    current: list[float]

    @property
    def ratios(self) -> list[float]:
        return [c / b if b else math.nan for b, c in zip(self.baseline, self.current, strict=True)]

    def as_json(self) -> dict[str, Any]:
        ratios = self.ratios
        return {
            "metric": self.metric,
            "unit": self.unit,
            "higher_is_better": self.higher_is_better,
            "baseline": self.baseline,
            "current": self.current,
            "ratios": ratios,
            "baseline_median": statistics.median(self.baseline),
            "current_median": statistics.median(self.current),
            "ratio_median": statistics.median(ratios),
            "ratio_min": min(ratios),
            "ratio_max": max(ratios),
        }


def summarise(baseline: Arm, current: Arm) -> list[Summary]:
    """A summary per metric both arms reported in every run, in the script's order."""
    summaries = []
    for metric, first in current.runs[0].items():
        if all(metric in run for run in baseline.runs + current.runs):
            summaries.append(
                Summary(
                    metric=metric,
                    unit=first.unit,
                    higher_is_better=first.higher_is_better,
                    baseline=[run[metric].value for run in baseline.runs],
                    current=[run[metric].value for run in current.runs],
                )
            )
    return summaries


def number(value: float) -> str:
    if not math.isfinite(value):
        return "n/a"
    if abs(value) >= 1000:
        return f"{value:,.0f}"
    return f"{value:.1f}" if abs(value) >= 10 else f"{value:#.3g}"


def machine() -> str:
    model = ""
    with contextlib.suppress(OSError):
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    return f"{model or 'unknown CPU'}, {os.cpu_count()} cores"


def markdown(report: dict[str, Any]) -> str:
    lines = [
        f"Command: `{report['command']}`",
        "",
        f"Baseline {report['baseline']}, current {report['current']}; {report['runs']} runs "
        f"each, alternating, baseline first; {report['script_note']}. Machine: "
        f"{report['machine']}; load average {report['load_before']:.1f} before, "
        f"{report['load_after']:.1f} after; {report['started']} UTC, "
        f"{report['minutes']:.0f} min.",
        "",
        "| metric | better | baseline median | current median | current / baseline "
        "(median of pairs) | pairs' range | runs |",
        "|---|---|---|---|---|---|---|",
    ]
    for item in report["metrics"]:
        unit = f" ({item['unit']})" if item["unit"] else ""
        lines.append(
            f"| {item['metric']}{unit} | {'higher' if item['higher_is_better'] else 'lower'} "
            f"| {number(item['baseline_median'])} | {number(item['current_median'])} "
            f"| **{item['ratio_median']:.3f}** "
            f"| {item['ratio_min']:.3f} to {item['ratio_max']:.3f} | {len(item['ratios'])} |"
        )
    return "\n".join(lines) + "\n"


def compare(rev: str, runs: int, script: Path, args: list[str]) -> dict[str, Any]:
    """Both arms' runs, alternating, and their report (``markdown`` prints it)."""
    script = script.resolve()
    if not script.is_file():
        raise RunFailed(f"no script {script}")
    top = Path(git("rev-parse", "--show-toplevel", cwd=script.parent))
    relative = script.relative_to(top)
    started, load_before = datetime.now(UTC), os.getloadavg()[0]
    with baseline_worktree(top, rev) as checkout:
        print(f"baseline worktree: {checkout}", flush=True)
        baseline = Arm(Tree("baseline", checkout, describe(checkout)), script, top)
        current = Arm(Tree("current", top, describe(top, work_tree=True)), script, top)
        for index in range(2 * runs):
            arm = (baseline, current)[index % 2]
            outcome = arm.run(args)
            if (
                index == 0
                and outcome.returncode != 0
                and IMPORT_FAILED.search(outcome.stderr)
                and (checkout / relative).is_file()
            ):
                print(
                    f"the current {relative} does not import against the baseline; "
                    "the baseline runs its own copy",
                    flush=True,
                )
                arm.script, arm.script_root = checkout / relative, checkout
                outcome = arm.run(args)
            where = f"run {index + 1} of {2 * runs} ({arm.tree.label}, {arm.tree.commit})"
            if outcome.returncode != 0:
                raise RunFailed(
                    f"{where} failed with exit status {outcome.returncode} after "
                    f"{outcome.seconds:.0f} s; its last lines:\n{outcome.tail()}"
                )
            try:
                figures = parse(outcome.stdout)
            except RunFailed as error:
                raise RunFailed(f"{where}: {error}; its last lines:\n{outcome.tail()}") from None
            arm.runs.append(figures)
            shown = ", ".join(
                f"{f.metric} {number(f.value)}{' ' + f.unit if f.unit else ''}"
                for f in figures.values()
            )
            print(f"{where}, {outcome.seconds:.0f} s: {shown}", flush=True)
    summaries = summarise(baseline, current)
    if not summaries:
        raise RunFailed(
            f"no metric both arms reported in every run (baseline: "
            f"{sorted(baseline.runs[0])}, current: {sorted(current.runs[0])})"
        )
    own = baseline.script != current.script
    return {
        "command": shlex.join(
            [
                *("python", "bench/compare.py", "--baseline", rev, "--runs", str(runs)),
                *("--", str(relative), *args),
            ]
        ),
        "baseline": baseline.tree.commit,
        "current": current.tree.commit,
        "runs": runs,
        "script_note": (
            f"the baseline ran its own {relative} (the current one does not import against it)"
            if own
            else f"both ran the current {relative}"
        ),
        "machine": machine(),
        "load_before": load_before,
        "load_after": os.getloadavg()[0],
        "started": started.strftime("%Y-%m-%d %H:%M"),
        "minutes": (datetime.now(UTC) - started).total_seconds() / 60,
        "metrics": [summary.as_json() for summary in summaries],
    }


def raise_interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt(f"signal {signum}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", required=True, help="a commit, branch or tag")
    parser.add_argument("--runs", type=int, default=5, help="runs of each arm")
    parser.add_argument("--markdown", type=Path, help="also write the table here")
    parser.add_argument("--json", type=Path, help="also write every figure here")
    parser.add_argument("script", type=Path)
    parser.add_argument("args", nargs=argparse.REMAINDER)
    options = parser.parse_args()
    if options.runs < 1:
        parser.error("--runs takes 1 or more")
    signal.signal(signal.SIGTERM, raise_interrupt)
    # A shell starts a background job with SIGINT ignored, and Python then leaves it so
    # (its runs too): an interrupt must stop a comparison however it was started.
    signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        report = compare(options.baseline, options.runs, options.script, options.args)
    except RunFailed as error:
        print(f"compare: {error}", file=sys.stderr)
        sys.exit(1)
    except KeyboardInterrupt:
        print("compare: interrupted; the baseline worktree is removed", file=sys.stderr)
        sys.exit(130)
    table = markdown(report)
    print()
    print(table, end="")
    if options.markdown:
        options.markdown.write_text(table)
    if options.json:
        options.json.write_text(json.dumps(report, indent=2) + "\n")


if __name__ == "__main__":
    main()
