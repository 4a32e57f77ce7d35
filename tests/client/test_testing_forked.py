"""The harness forks ``adserver`` from preloaded imports (adclient.testing.forked): the
forked program is the installed one with the arguments, environment and folder it is
given, exits as the command does, and AD_TESTING_EXEC=1 starts it by command."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import httpx
import pytest

from adclient.testing.forked import ForkedProcess, run_adserver
from adclient.testing.servers import SDK_HEADERS, ServerProcess, free_port

pytestmark = pytest.mark.e2e


def test_a_forked_server_runs_with_its_own_environment_and_stops(tmp_path: Path) -> None:
    url = f"sqlite:///{tmp_path / 'studies.db'}"
    server = ServerProcess(database_url=url, workdir=tmp_path, env={"AD_MAX_BODY_BYTES": "2000"})
    server.start()
    try:
        assert isinstance(server.process, ForkedProcess)
        assert server.process.pid != os.getpid()
        body = {"name": "x" * 3000, "space": {"type": "box", "params": []}}
        answer = httpx.post(f"{server.url}/api/v1/studies", json=body, headers=SDK_HEADERS)
        assert answer.status_code == 413  # its own AD_MAX_BODY_BYTES, not this process's
        assert (tmp_path / "studies.db").is_file()
    finally:
        server.stop()
    assert server.process.poll() is not None


def test_a_forked_command_exits_as_the_command_does(tmp_path: Path) -> None:
    argv = ["token", "create", "--role", "emperor", "--database-url", "sqlite://"]
    output = tmp_path / "out"
    assert run_adserver(argv, env=os.environ, cwd=tmp_path, output=output) == 2
    forked = output.read_text()
    adserver = Path(sys.executable).with_name("adserver")
    done = subprocess.run([str(adserver), *argv], capture_output=True, text=True)
    assert done.returncode == 2
    assert "unknown role 'emperor'" in forked
    assert forked.strip() == done.stderr.strip()


def test_exec_is_used_when_asked(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("AD_TESTING_EXEC", "1")
    server = ServerProcess(database_url=f"sqlite:///{tmp_path / 's.db'}", workdir=tmp_path)
    server.start()
    try:
        assert isinstance(server.process, subprocess.Popen)
    finally:
        server.stop()


def test_a_fork_server_that_cannot_start_falls_back_to_the_command(tmp_path: Path) -> None:
    """The fork server's socket lives in TMPDIR; past 107 characters it cannot bind (as
    under bench/compare.py's worktrees), and the server is started by command instead."""
    deep = tmp_path / ("t" * 60) / ("u" * 60)
    deep.mkdir(parents=True)
    script = (
        "import sys; from pathlib import Path\n"
        "from adclient.testing.servers import ServerProcess\n"
        "from adclient.testing import forked\n"
        "work = Path(sys.argv[1])\n"
        "server = ServerProcess(database_url=f'sqlite:///{work}/s.db', workdir=work).start()\n"
        "print(type(server.process).__name__, bool(forked._BROKEN))\n"
        "server.stop()\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", script, str(tmp_path)],
        env={**os.environ, "TMPDIR": str(deep)},
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == ["Popen", "True"]


FIRST_START = """
import importlib, os, signal, sys, threading, time, urllib.request
from adclient.testing.forked import PRELOAD, _program
for name in PRELOAD:
    try:
        importlib.import_module(name)
    except ImportError:
        pass
program = _program()
program.load()
port, url = sys.argv[1], sys.argv[2]
before = set(sys.modules)

def report():
    while True:
        try:
            urllib.request.urlopen(f"http://127.0.0.1:{port}/healthz", timeout=1).read()
            break
        except OSError:
            time.sleep(0.1)
    print("imported:", *sorted(set(sys.modules) - before), flush=True)
    os.kill(os.getpid(), signal.SIGTERM)

threading.Thread(target=report, daemon=True).start()
sys.argv = ["adserver", "--port", port, "--database-url", url, "--log-level", "warning"]
program.load()()
"""


def test_the_fork_server_preloads_every_module_a_server_imports_to_start(
    tmp_path: Path,
) -> None:
    """What a forked server would import as it starts (first start: it migrates an empty
    SQLite file) and answers, it imports again on every start: all of it is preloaded."""
    url = f"sqlite:///{tmp_path / 'studies.db'}"
    done = subprocess.run(
        [sys.executable, "-c", FIRST_START, str(free_port()), url],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert "imported:" in done.stdout, done.stderr
    assert done.stdout.split("imported:", 1)[1].split() == []
