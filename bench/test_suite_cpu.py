"""bench/suite_cpu.py, run as a program on two tests of its own: one that spends CPU in
the test process, one whose child process spends it."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]

BURNERS = """
import subprocess, sys, time

def burn(seconds):
    end = time.process_time() + seconds
    while time.process_time() < end:
        pass

def test_in_process():
    burn(0.5)

def test_in_a_child():
    code = "import time\\nend = time.process_time() + 0.5\\nwhile time.process_time() < end: pass"
    subprocess.run([sys.executable, "-c", code], check=True)
"""


def test_each_tests_cpu_counts_its_own_and_its_childrens(tmp_path: Path) -> None:
    (tmp_path / "test_burners.py").write_text(BURNERS)
    out = tmp_path / "lines"
    done = subprocess.run(
        [sys.executable, str(REPO_ROOT / "bench" / "suite_cpu.py"), "--out", str(out), "--",
         str(tmp_path / "test_burners.py"), "-p", "no:cacheprovider", "--rootdir", str(tmp_path)],
        cwd=REPO_ROOT, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr
    rows = {
        row["id"].split("::")[1]: row
        for path in out.glob("cpu-*.jsonl")
        for row in map(json.loads, path.open())
    }
    assert set(rows) == {"test_in_process", "test_in_a_child"}
    assert rows["test_in_process"]["own"] >= 0.45 > rows["test_in_process"]["kids"]
    assert rows["test_in_a_child"]["kids"] >= 0.45 > rows["test_in_a_child"]["own"]
    assert "2 tests" in done.stdout and "test_burners.py" in done.stdout


def test_a_failing_suite_is_its_exit_status(tmp_path: Path) -> None:
    (tmp_path / "test_fails.py").write_text("def test_fails():\n    assert False\n")
    done = subprocess.run(
        [sys.executable, str(REPO_ROOT / "bench" / "suite_cpu.py"), "--",
         str(tmp_path / "test_fails.py"), "-p", "no:cacheprovider", "--rootdir", str(tmp_path)],
        cwd=REPO_ROOT, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert done.returncode == 1
    assert "1 tests" in done.stdout
