"""deploy/slurm/adworkers.sbatch without SLURM: run as sbatch would run one array task
(its SLURM_* variables set), with a stand-in ``adworker`` in the virtual environment it
activates, it execs the worker with options the real CLI knows, the token read from its
file into AD_TOKEN (never an argument), and SIGTERM asked for before the time limit."""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import pytest

from tests.program_checks import check_command, check_environment

SCRIPT = Path(__file__).resolve().parents[1] / "deploy" / "slurm" / "adworkers.sbatch"
TOKEN = "adt_slurm-test-token"


def directives() -> dict[str, str]:
    found: dict[str, str] = {}
    for line in SCRIPT.read_text().splitlines():
        if line.startswith("#SBATCH --"):
            name, _, value = line.removeprefix("#SBATCH ").partition("=")
            found[name] = value
    return found


def test_the_script_is_a_job_array_that_asks_for_sigterm_before_its_limit() -> None:
    subprocess.run(["bash", "-n", str(SCRIPT)], check=True)
    assert os.access(SCRIPT, os.X_OK)
    options = directives()
    assert options["--array"] and "%a" in options["--output"]
    assert options["--signal"].startswith("B:TERM@")
    assert "exec adworker" in SCRIPT.read_text()


@pytest.fixture
def fake_venv(tmp_path: Path) -> Path:
    """A virtual environment whose ``adworker`` writes what it was given and exits."""
    venv = tmp_path / "venv"
    (venv / "bin").mkdir(parents=True)
    (venv / "bin" / "activate").write_text(f'PATH="{venv / "bin"}:$PATH"\n')
    adworker = venv / "bin" / "adworker"
    adworker.write_text(
        "#!/usr/bin/env python3\n"
        "import json, os, sys\n"
        "env = {k: v for k, v in os.environ.items() if k.startswith('AD_')}\n"
        "with open(os.environ['RECORD'], 'w') as f:\n"
        "    json.dump({'argv': sys.argv[1:], 'env': env, 'pid': os.getpid()}, f)\n"
    )
    adworker.chmod(0o755)
    return venv


def run_task(tmp_path: Path, venv: Path, **extra: str) -> subprocess.CompletedProcess[str]:
    token_file = tmp_path / "worker-token"
    token_file.write_text(TOKEN + "\n")
    token_file.chmod(0o600)
    env = {
        "PATH": os.environ["PATH"],
        "HOME": str(tmp_path),
        "TMPDIR": str(tmp_path),
        "RECORD": str(tmp_path / "record.json"),
        "ACTIVEDESIGN_VENV": str(venv),
        "ACTIVEDESIGN_TOKEN_FILE": str(token_file),
        "SLURM_ARRAY_JOB_ID": "4242",
        "SLURM_ARRAY_TASK_ID": "7",
        "SLURM_CPUS_PER_TASK": "4",
        **extra,
    }
    return subprocess.run(
        ["bash", str(SCRIPT)], env=env, capture_output=True, text=True, timeout=30
    )


def test_an_array_task_execs_adworker_with_the_token_from_its_file(
    tmp_path: Path, fake_venv: Path
) -> None:
    done = run_task(tmp_path, fake_venv, AD_SERVER_URL="https://design.example.org")
    assert done.returncode == 0, done.stderr
    record = json.loads((tmp_path / "record.json").read_text())
    argv = ["adworker", *record["argv"]]
    check_command(argv)
    check_environment("adworker", record["env"])
    assert record["env"]["AD_TOKEN"] == TOKEN and TOKEN not in " ".join(argv)
    assert record["env"]["AD_SERVER_URL"] == "https://design.example.org"
    assert argv[argv.index("--concurrency") + 1] == "4"
    assert argv[argv.index("--worker-id") + 1] == "slurm-4242-7"
    assert Path(argv[argv.index("--workdir") + 1]).is_dir()


def test_without_a_server_url_the_task_says_so_and_fails(tmp_path: Path, fake_venv: Path) -> None:
    done = run_task(tmp_path, fake_venv)
    assert done.returncode != 0 and "AD_SERVER_URL" in done.stderr
    assert not (tmp_path / "record.json").exists()
