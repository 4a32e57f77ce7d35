"""bench/compare.py, run as a program on a small git repository of two commits whose
code differs (``fakecode.SPEED``: 1 at the baseline, 2 now) and on a real bench."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from bench.compare import RunFailed, parse

FAKE = str(Path("bench", "fake.py"))
"""The fake repository's bench script (not a file of this repository)."""
SLEEPER = str(Path("bench", "sleep.py"))

REPO_ROOT = Path(__file__).resolve().parents[1]
COMPARE = REPO_ROOT / "bench" / "compare.py"

# A bench: it reads the code of its arm, also from a child process (as a server a bench
# starts), logs what the child read, and reports figures that grow from run to run.
FAKE_BENCH = """\
import json, subprocess, sys
from pathlib import Path

import fakecode

log = Path(sys.argv[1])
child = subprocess.run(
    [sys.executable, "-c", "import fakecode; print(fakecode.SPEED)"],
    capture_output=True, text=True, check=True,
)
runs = log.read_text().splitlines() if log.exists() else []
log.write_text("".join(line + "\\n" for line in [*runs, child.stdout.strip()]))
value = fakecode.SPEED * (len(runs) + 1)
print("a human line")
print("BENCH " + json.dumps({"metric": "speed", "value": value, "higher_is_better": True,
                             "unit": "x/s"}))
print("BENCH " + json.dumps({"metric": "cost", "value": 1 / value, "higher_is_better": False}))
"""


def git(repo: Path, *args: str) -> str:
    command = ["git", "-c", "user.name=t", "-c", "user.email=t@example.org", *args]
    return subprocess.run(command, cwd=repo, check=True, capture_output=True, text=True).stdout


def commit(repo: Path, files: dict[str, str], message: str) -> None:
    for name, text in files.items():
        path = repo / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    git(repo, "add", "-A")
    git(repo, "commit", "-q", "-m", message)


@pytest.fixture
def repo(tmp_path: Path) -> Path:
    """A repository whose HEAD~1 has SPEED 1 and HEAD SPEED 2, both with the fake bench."""
    repo = tmp_path / "repo"
    repo.mkdir()
    git(repo, "init", "-q")
    commit(
        repo,
        {"service/fakecode/__init__.py": "SPEED = 1.0\n", FAKE: FAKE_BENCH},
        "baseline",
    )
    commit(repo, {"service/fakecode/__init__.py": "SPEED = 2.0\n"}, "current")
    return repo


def run_compare(tmp_path: Path, *args: str) -> subprocess.CompletedProcess[str]:
    """compare.py as a program; its temporary folders go under ``tmp_path/temp``. No
    bytecode caches: a test rewrites a fake module within a second at the same size,
    which a cached .pyc (keyed on mtime and size) would hide."""
    temp = tmp_path / "temp"
    temp.mkdir(exist_ok=True)
    env = {**os.environ, "TMPDIR": str(temp), "PYTHONDONTWRITEBYTECODE": "1"}
    return subprocess.run(
        [sys.executable, str(COMPARE), *args], capture_output=True, text=True, env=env
    )


def run_fake(
    repo: Path, tmp_path: Path, baseline: str, runs: int = 5
) -> tuple[subprocess.CompletedProcess[str], Path, Path]:
    """compare.py on the repository's fake bench (FAKE): its answer, the bench's log, the report."""
    log, report = tmp_path / "log", tmp_path / "report.json"
    done = run_compare(
        tmp_path, "--baseline", baseline, "--runs", str(runs), "--json", str(report),
        "--", str(repo / FAKE), str(log),
    )  # fmt: skip
    return done, log, report


def assert_no_worktree_left(repo: Path, tmp_path: Path) -> None:
    assert git(repo, "worktree", "list", "--porcelain").count("worktree ") == 1
    assert list((tmp_path / "temp").iterdir()) == []


def test_runs_alternate_on_each_trees_code_and_ratios_pair_runs(repo: Path, tmp_path: Path) -> None:
    done, log, report = run_fake(repo, tmp_path, "HEAD~1", runs=4)
    assert done.returncode == 0, done.stderr
    # baseline, current, ...: each run's child process imported its own tree's code
    assert log.read_text().split() == ["1.0", "2.0"] * 4
    speed, cost = json.loads(report.read_text())["metrics"]
    assert speed["baseline"] == [1.0, 3.0, 5.0, 7.0]  # runs 1, 3, 5, 7
    assert speed["current"] == [4.0, 8.0, 12.0, 16.0]  # runs 2, 4, 6, 8
    assert speed["ratios"] == pytest.approx([4.0, 8 / 3, 12 / 5, 16 / 7])
    assert speed["ratio_median"] == pytest.approx((8 / 3 + 12 / 5) / 2)  # not 10 / 4
    assert (speed["ratio_min"], speed["ratio_max"]) == pytest.approx((16 / 7, 4.0))
    assert cost["higher_is_better"] is False
    assert cost["ratio_median"] == pytest.approx((3 / 8 + 5 / 12) / 2)
    head, base = (git(repo, "rev-parse", "--short", r).strip() for r in ("HEAD", "HEAD~1"))
    assert f"Baseline {base} (" in done.stdout and f"current {head} (" in done.stdout
    assert "4 runs each, alternating" in done.stdout
    assert "| speed (x/s) | higher | 4.00 | 10.0 | **2.533** | 2.286 to 4.000 | 4 |" in done.stdout
    assert_no_worktree_left(repo, tmp_path)


def test_uncommitted_changes_to_the_code_are_named_and_others_not(
    repo: Path, tmp_path: Path
) -> None:
    (repo / "notes.md").write_text("tracked, not code\n")
    commit(repo, {}, "notes")
    (repo / "notes.md").write_text("changed\n")
    done, _, _ = run_fake(repo, tmp_path, "HEAD~1", runs=1)
    assert done.returncode == 0, done.stderr
    assert "+ uncommitted changes" not in done.stdout
    (repo / "service/fakecode/__init__.py").write_text("SPEED = 3.0\n")
    done, log, _ = run_fake(repo, tmp_path, "HEAD~1", runs=1)
    assert done.returncode == 0, done.stderr
    assert "+ uncommitted changes" in done.stdout
    assert log.read_text().split()[-2:] == ["2.0", "3.0"]  # the work tree's code, as it is


def test_a_failing_run_stops_with_its_exit_status_and_last_lines(
    repo: Path, tmp_path: Path
) -> None:
    failing = FAKE_BENCH.replace(
        "import fakecode\n",
        "import fakecode\nif fakecode.SPEED > 1:\n    print('the current code broke')\n"
        "    sys.exit(3)\n",
    )
    commit(repo, {FAKE: failing}, "a bench that fails on the current code")
    done, _, _ = run_fake(repo, tmp_path, "HEAD~2")
    head = git(repo, "rev-parse", "--short", "HEAD").strip()
    assert done.returncode == 1
    assert f"run 2 of 10 (current, {head} " in done.stderr
    assert "failed with exit status 3" in done.stderr
    assert "the current code broke" in done.stderr
    assert "Traceback" not in done.stderr
    assert_no_worktree_left(repo, tmp_path)


def test_a_run_without_a_result_line_stops_it(repo: Path, tmp_path: Path) -> None:
    commit(repo, {FAKE: "print('figures, but not as result lines')\n"}, "no lines")
    done = run_compare(tmp_path, "--baseline", "HEAD~2", "--", str(repo / FAKE))
    assert done.returncode == 1
    assert "run 1 of 10 (baseline, " in done.stderr and "no result line" in done.stderr
    assert "figures, but not as result lines" in done.stderr
    assert_no_worktree_left(repo, tmp_path)


def test_an_unknown_baseline_is_named(repo: Path, tmp_path: Path) -> None:
    done = run_compare(tmp_path, "--baseline", "no-such-rev", "--", str(repo / FAKE))
    assert done.returncode == 1
    assert "no-such-rev" in done.stderr and "Traceback" not in done.stderr
    assert_no_worktree_left(repo, tmp_path)


def test_a_script_that_does_not_import_against_the_baseline_runs_the_baselines_own(
    repo: Path, tmp_path: Path
) -> None:
    commit(
        repo,
        {
            "service/fakecode/extra.py": "BONUS = 0.0\n",
            FAKE: FAKE_BENCH.replace("import fakecode\n", "import fakecode.extra\n"),
        },
        "the bench imports a module the baseline lacks",
    )
    done, _, report = run_fake(repo, tmp_path, "HEAD~2", runs=2)
    assert done.returncode == 0, done.stderr
    assert "the baseline runs its own copy" in done.stdout
    assert f"the baseline ran its own {FAKE}" in done.stdout
    assert json.loads(report.read_text())["metrics"][0]["baseline"] == [1.0, 3.0]
    assert_no_worktree_left(repo, tmp_path)


def test_interrupted_it_stops_the_run_and_removes_the_worktree(repo: Path, tmp_path: Path) -> None:
    started, stopped = tmp_path / "started", tmp_path / "stopped"
    sleeper = textwrap.dedent(f"""\
        import time
        from pathlib import Path
        Path({str(started)!r}).write_text("yes")
        try:
            time.sleep(600)
        except KeyboardInterrupt:
            Path({str(stopped)!r}).write_text("cleaned up")
        """)
    commit(repo, {SLEEPER: sleeper}, "a bench that sleeps")
    temp = tmp_path / "temp"
    temp.mkdir()
    process = subprocess.Popen(
        [sys.executable, str(COMPARE), "--baseline", "HEAD", "--", str(repo / SLEEPER)],
        env={**os.environ, "TMPDIR": str(temp)},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        while not started.exists() and process.poll() is None:
            time.sleep(0.05)
        process.send_signal(signal.SIGINT)
        _, stderr = process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    assert process.returncode == 130
    assert "interrupted" in stderr
    assert stopped.read_text() == "cleaned up"  # the script had its chance to stop servers
    assert_no_worktree_left(repo, tmp_path)


@pytest.mark.parametrize(
    "line, why",
    [
        ('BENCH {"metric": "a", "value": 1}', "does not parse"),
        ('BENCH {"metric": "a", "value": true, "higher_is_better": true}', "wrong types"),
        ('BENCH {"metric": "a", "value": "1", "higher_is_better": true}', "wrong types"),
        ("BENCH not json", "does not parse"),
        ("bench lower case is not a result line", "no result line"),
    ],
)
def test_a_bad_result_line_is_named(line: str, why: str) -> None:
    with pytest.raises(RunFailed, match=why):
        parse(line + "\n")


def test_a_metric_twice_in_one_run_is_refused() -> None:
    line = 'BENCH {"metric": "a", "value": 1, "higher_is_better": true}\n'
    with pytest.raises(RunFailed, match="'a' reported twice"):
        parse(line + line)


def test_a_real_bench_against_its_own_commit_gives_a_ratio_near_one(tmp_path: Path) -> None:
    """bench/server_cpu.py, smallest size, against HEAD: real adserver processes on
    SQLite, the baseline's from the worktree; the same code within the noise."""
    report = tmp_path / "report.json"
    done = run_compare(
        tmp_path, "--baseline", "HEAD", "--runs", "1", "--json", str(report),
        "--", str(REPO_ROOT / "bench/server_cpu.py"), "--runs", "1", "--clients", "1",
        "--cycles", "30",
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    metrics = {m["metric"]: m for m in json.loads(report.read_text())["metrics"]}
    cpu = metrics["server CPU per cycle"]
    assert cpu["unit"] == "ms" and cpu["higher_is_better"] is False
    assert 1 / 3 < cpu["ratio_median"] < 3  # loose: two single runs on a shared machine
    assert "both ran the current bench/server_cpu.py" in done.stdout
    assert list((tmp_path / "temp").iterdir()) == []
