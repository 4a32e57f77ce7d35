"""What bench/paper.py and bench/best_known.py share: the tasks, files and JSONL records."""

from __future__ import annotations

import argparse
import json
import math
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import yaml

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / "bench" / "results"
BEST_KNOWN = RESULTS / "best_known.json"
QUICK = REPO / "var" / "paper" / "quick"
"""Where --quick (smoke) runs of both scripts write everything: ignored by git."""
MODEL_BUDGET = 15
"""qei's evaluations per study (the preprint's budget)."""
BASELINE_BUDGET = 30
"""The other methods' evaluations per study."""
DEFAULT_SEEDS = {"fast": 10}
"""Seeds per learner; RL learners get RL_SEEDS."""
RL_SEEDS = 3
TARGET_FRACTION = 0.95
"""A study reaches the target when a trial scores at least this fraction of the best known."""

TASKS: dict[str, str] = {
    "stand-up": "stand-up.yaml",
    "diagonal-gesture": "diagonal-gesture.yaml",
    "lift-highest": "multi-structure.yaml",
}
"""Task name (as workers know it) -> the example study (under examples/) that defines it."""

TASK_LABELS = {
    "stand-up": "stand-up",
    "diagonal-gesture": "diagonal-gesture",
    "lift-highest": "lift-highest (multi-structure)",
}


def code_root() -> Path:
    """Where the code under test lives: the pinned snapshot once ``use_snapshot`` ran."""
    return Path(os.environ.get("PAPER_CODE_ROOT", str(REPO)))


def study_body(task: str) -> dict[str, Any]:
    """The example StudyCreate body of a task, as a plain dict (YAML comments dropped)."""
    path = code_root() / "examples" / TASKS[task]
    body = yaml.safe_load(path.read_text())
    if body["task"]["name"] != task:
        raise ValueError(f"{path} defines task {body['task']['name']!r}, not {task!r}")
    return body


def read_jsonl(path: Path) -> list[dict[str, Any]]:
    """Every complete record of a JSONL file (a line cut short by a crash is skipped)."""
    if not path.exists():
        return []
    records = []
    for line in path.read_text().splitlines():
        try:
            records.append(json.loads(line))
        except json.JSONDecodeError:
            continue
    return records


def append_jsonl(path: Path, record: dict[str, Any]) -> None:
    """Append one record and flush it to disk, so a killed run loses at most the one in flight."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("a+b") as handle:
        # a line cut short by a crash stays a line of its own (read_jsonl skips it)
        handle.seek(0, os.SEEK_END)
        if handle.tell():
            handle.seek(-1, os.SEEK_END)
            if handle.read(1) != b"\n":
                handle.write(b"\n")
        handle.write((json.dumps(record, separators=(",", ":")) + "\n").encode())
        handle.flush()
        os.fsync(handle.fileno())


def arms_parser(
    doc: str, arms: tuple[str, ...], results: Path, *, seeds: int, workers: int, timeout: float
) -> argparse.ArgumentParser:
    """The options every arms-against-arms study benchmark takes (bench/ties.py,
    bench/tree_looks.py): seeds, workers, arms, a study's timeout, the results file and
    ``--report``."""
    parser = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=seeds)
    parser.add_argument("--workers", type=int, default=workers)
    parser.add_argument("--arms", nargs="+", choices=arms, default=list(arms))
    parser.add_argument("--timeout", type=float, default=timeout)
    parser.add_argument("--results", type=Path, default=results)
    parser.add_argument("--report", action="store_true", help="print the table and stop")
    return parser


def run_missing(
    path: Path,
    runs: list[dict[str, Any]],
    cells: list[dict[str, Any]],
    run: Callable[[dict[str, Any]], dict[str, Any]],
) -> None:
    """Run each cell (the fields that name a run) that no record of ``runs`` matches,
    appending each finished run to ``path`` and to ``runs`` and printing its best: a
    killed benchmark resumes where it stopped."""
    for cell in cells:
        if any(all(record.get(k) == v for k, v in cell.items()) for record in runs):
            continue
        record = run(cell)
        append_jsonl(path, record)
        runs.append(record)
        named = " ".join(f"{k} {v}" for k, v in cell.items())
        print(f"{named}: best {record['best']:.3f} ({record['wall_s']:.0f} s)", flush=True)


def quantiles(values: list[float], qs: tuple[float, ...] = (0.25, 0.5, 0.75)) -> list[float]:
    """Quantiles by linear interpolation; ``inf`` values (censored) sort last, so a
    quantile that falls among them is ``inf``."""
    ordered = sorted(values)
    out = []
    for q in qs:
        if not ordered:
            out.append(math.nan)
            continue
        position = q * (len(ordered) - 1)
        low, high = math.floor(position), math.ceil(position)
        a, b = ordered[low], ordered[high]
        if math.isinf(a) or math.isinf(b):
            out.append(math.inf if (math.isinf(b) and position > low) or math.isinf(a) else a)
        else:
            out.append(a + (b - a) * (position - low))
    return out


# -- a frozen copy of the code under test ----------------------------------------------

CODE_REF = RESULTS / "code_ref"
"""The commit whose client/service/workers/examples every paper run uses (see ``snapshot``)."""
SNAPSHOTS = REPO / "var" / "paper" / "code"
SNAPSHOT_PARTS = ("client", "service", "workers", "examples", "migrations", "alembic.ini")


def code_ref() -> str:
    """The pinned commit: ``bench/results/code_ref`` if present, else HEAD (then pinned).

    Runs take hours in a working tree that other engineers edit; pinning one commit
    keeps every study and the best-known scores on one version of the tasks, the
    learners and the proposers. Delete the file (and the results) to move on.
    """
    import subprocess

    if CODE_REF.exists():
        return CODE_REF.read_text().strip()
    sha = subprocess.run(
        ["git", "rev-parse", "HEAD"], cwd=REPO, check=True, capture_output=True, text=True
    ).stdout.strip()
    CODE_REF.parent.mkdir(parents=True, exist_ok=True)
    CODE_REF.write_text(sha + "\n")
    return sha


def snapshot(sha: str) -> Path:
    """``git archive`` of the pinned commit's packages and examples, extracted once."""
    import subprocess
    import tarfile
    import tempfile

    target = SNAPSHOTS / sha
    if (target / ".complete").exists():
        return target
    target.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as scratch:
        archive = Path(scratch) / "code.tar"
        subprocess.run(
            ["git", "archive", "--format=tar", "-o", str(archive), sha, *SNAPSHOT_PARTS],
            cwd=REPO,
            check=True,
        )
        with tarfile.open(archive) as tar:
            tar.extractall(target, filter="data")
    (target / ".complete").write_text(sha + "\n")
    return target


def snapshot_paths(root: Path) -> list[str]:
    return [str(root / "client"), str(root / "service"), str(root / "workers")]


def use_snapshot(
    quick: bool = False, ref: str | None = None, workers_checked: bool = False
) -> tuple[str, Path]:
    """Put the pinned code (or the commit ``ref``) first on this process's path (and its
    children's PYTHONPATH). ``ref`` is refused when its workers/ differ from the pin's,
    unless ``workers_checked`` (the scores were shown to agree).

    Call before importing adclient/adservice/adworker. ``quick`` runs use the working
    tree as it is (smoke runs only).
    """
    import subprocess
    import sys

    if quick:
        return "working-tree", REPO
    sha = code_ref()
    if ref is not None:
        newer = subprocess.run(
            ["git", "rev-parse", ref], cwd=REPO, check=True, capture_output=True, text=True
        ).stdout.strip()
        # the tasks and learners must be those the best-known scores were measured with
        changed = subprocess.run(["git", "diff", "--quiet", sha, newer, "--", "workers"], cwd=REPO)
        if changed.returncode != 0 and not workers_checked:
            raise SystemExit(f"workers/ differs between the pinned {sha[:12]} and {ref}")
        sha = newer
    root = snapshot(sha)
    paths = snapshot_paths(root)
    sys.path[:0] = paths
    os.environ["PYTHONPATH"] = os.pathsep.join(
        [*paths, *filter(None, [os.environ.get("PYTHONPATH")])]
    )
    os.environ["PAPER_CODE_ROOT"] = str(root)
    return sha, root


def interrupt_on_sigterm() -> None:
    """SIGTERM (kill PID) unwinds like Ctrl-C, so pools, workers and the server stop too."""
    import signal

    def handler(signum: int, frame: object) -> None:
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, handler)
