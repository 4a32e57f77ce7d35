"""The harness forks ``adserver`` and ``adworker`` from preloaded imports
(adclient.testing.forked): the forked program is the installed one with the arguments,
environment and folder it is given, starts as the exec'd one would (its temporary
folder, torch threads, signal handlers), exits as the command does, and
AD_TESTING_EXEC=1 starts it by command."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import tomllib
from pathlib import Path

import httpx
import pytest

from adclient import Client
from adclient.testing import forked
from adclient.testing.forked import ForkedProcess, run_adserver
from adclient.testing.servers import SDK_HEADERS, ServerProcess, free_port
from adclient.testing.workers import (
    ADCLIENT,
    ADWORKER,
    PATIENCE,
    WorkerProcess,
    plugin_path,
    run_adclient,
    run_adworker,
)

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


PLUGIN = Path(__file__).resolve().parents[1] / "workers" / "plugin_fixture"


def installed_plugin(site: Path) -> Path:
    """tests/workers/plugin_fixture as ``pip install --target site`` leaves it: the
    package, and its dist-info with the entry points."""
    shutil.copytree(PLUGIN / "adplugin_reach", site / "adplugin_reach")
    info = site / "adplugin_reach-0.1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: adplugin-reach\nVersion: 0.1.0\n")
    project = tomllib.loads((PLUGIN / "pyproject.toml").read_text())["project"]
    (info / "entry_points.txt").write_text(
        "".join(
            f"[{group}]\n" + "".join(f"{name} = {value}\n" for name, value in points.items())
            for group, points in project["entry-points"].items()
        )
    )
    return site


def test_a_program_with_a_plugin_folder_is_forked_and_finds_the_plugin(tmp_path: Path) -> None:
    """A plugin installed in a folder of its own, before this process's PYTHONPATH: the
    forked adworker lists its tasks as the command does; a folder holding a module or a
    distribution this process finds elsewhere means the command."""
    env = plugin_path(installed_plugin(tmp_path / "site"))
    assert forked.can_fork({**os.environ, **env}, "adworker")
    done = run_adworker("tasks", **env)
    command = subprocess.run(
        [str(ADWORKER), "tasks"], env={**os.environ, **env}, capture_output=True, text=True
    )
    pybullet_says = "pybullet build time"  # as it is imported: the fork server's, forked
    said = [line for line in command.stderr.splitlines() if pybullet_says not in line]
    assert (done.returncode, done.stdout, done.stderr.splitlines()) == (
        command.returncode,
        command.stdout,
        said,
    )
    assert any(line.split()[:1] == ["reach-up"] for line in done.stdout.splitlines()), done.stdout
    for shadowing in ("yaml", "pydantic-2.0.dist-info"):
        (tmp_path / f"with-{shadowing}" / shadowing).mkdir(parents=True)
        assert not forked.can_fork({**os.environ, **plugin_path(tmp_path / f"with-{shadowing}")})


def test_a_script_without_a_main_guard_is_told_why_its_server_ended(tmp_path: Path) -> None:
    """A forked server imports the calling script again, as ``multiprocessing`` does; a
    script that starts one at import time ends it before it writes any output. The
    error says so (it was a FileNotFoundError for the missing log)."""
    env = {k: v for k, v in os.environ.items() if k != "AD_TESTING_EXEC"}
    if not forked.can_fork(env):
        pytest.skip(
            "SKIPPED: adserver is started by command here (AD_TESTING_EXEC=1, a PYTHONPATH "
            "it cannot fork with, or no fork server), so no fork server imports the script "
            "again and there is no early end to explain"
        )
    script = tmp_path / "unguarded.py"
    script.write_text(
        "import sys; from pathlib import Path\n"
        "from adclient.testing.servers import ServerProcess\n"
        "work = Path(sys.argv[1])\n"
        "server = ServerProcess(database_url=f'sqlite:///{work}/s.db', workdir=work).start()\n"
        "server.stop()\n"
    )
    done = subprocess.run(
        [sys.executable, str(script), str(tmp_path)],
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode != 0
    assert "FileNotFoundError" not in done.stderr, done.stderr[-2000:]
    assert "adserver exited early" in done.stderr, done.stderr[-2000:]
    assert 'if __name__ == "__main__":' in done.stderr, done.stderr[-2000:]


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
for name in PRELOAD["adserver"]:
    try:
        importlib.import_module(name)
    except ImportError:
        pass
program = _program("adserver")
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


PROBE = """
import gc, os, signal, subprocess, sys, tempfile, torch
import gymnasium
from stable_baselines3 import PPO

FRESH = "import sys; print(*sys.path[1:], sep=chr(10))"
EXECD = [os.path.dirname(sys.executable), *subprocess.run(
    [sys.executable, "-c", FRESH], capture_output=True, text=True
).stdout.splitlines()]


def probe(job):
    \"\"\"What the worker process is like when it runs a job (torch is preloaded when forked).\"\"\"
    before = set(sys.modules)
    PPO("MlpPolicy", gymnasium.make("Pendulum-v1"), n_steps=64, batch_size=64, device="cpu")
    torch_modules = {name for name in sys.modules if name.split(".")[0] in ("torch", "sympy")}
    return {
        "torch_modules_a_model_imports": float(len(torch_modules - before)),
        "value": job.params["x"],
        "torch_threads": torch.get_num_threads(),
        "own_tmpdir": float(tempfile.gettempdir() == os.environ["TMPDIR"]),
        "own_variable": float(os.environ.get("PROBE_ONLY") == "yes"),
        "ignores_sigterm": float(signal.getsignal(signal.SIGTERM) == signal.SIG_IGN),
        "preloaded_frozen": float(gc.get_freeze_count() > 0),
        "path_as_execd": float(sys.path == [os.path.dirname(__file__), *EXECD]),
    }
"""


def test_a_forked_worker_starts_as_an_execd_one(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """torch, imported in the fork server, takes the thread count the worker sets from
    OMP_NUM_THREADS (1 where unset); the temporary folder is the worker's own TMPDIR; the
    environment and ``sys.path`` are its own; the job's process ignores SIGTERM, which
    reaches the worker's handler and ends it with 0; the objects the fork server made
    are frozen (the worker's collections do not copy their pages); what a learner's
    first model imports is preloaded."""
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    app, tmp = tmp_path / "app", tmp_path / "tmp"
    app.mkdir()
    tmp.mkdir()
    (app / "probe.py").write_text(PROBE)
    server = ServerProcess(database_url=f"sqlite:///{tmp_path / 's.db'}", workdir=tmp_path)
    server.start()
    worker = None
    try:
        with Client(server.url) as client:
            study = client.create_study(
                name="probe",
                direction="minimize",
                space={"type": "box", "params": [{"name": "x", "low": 0, "high": 1}]},
                proposer={"name": "random", "seed": 1},
                task={"name": "probe", "external": True},
                max_trials=1,
            )
            args = ["--app-dir", str(app), "--function", "probe:probe", "--task", "probe"]
            worker = WorkerProcess(
                server, tmp_path, "probe", *args, env={"TMPDIR": str(tmp), "PROBE_ONLY": "yes"}
            )
            assert isinstance(worker.process, ForkedProcess)
            assert study.wait(poll=0.2, timeout=PATIENCE).n_complete == 1, worker.log()
            (trial,) = study.trials
            assert trial.metrics["torch_threads"] == 1
            assert trial.metrics["own_tmpdir"] == 1.0
            assert trial.metrics["own_variable"] == 1.0
            # the job runs in the worker's job process, which leaves SIGTERM to the worker
            # (its stop grace); the worker's handler ends it with 0 below
            assert trial.metrics["ignores_sigterm"] == 1.0
            assert trial.metrics["preloaded_frozen"] == 1.0  # its collections skip them
            assert trial.metrics["path_as_execd"] == 1.0  # not pytest's sys.path
            # A learner's first model (its optimizer) imports nothing of torch's (its
            # compiler, 1.7 s of CPU, was imported there in every worker).
            assert trial.metrics["torch_modules_a_model_imports"] == 0
            worker.signal(signal.SIGTERM)
            assert worker.wait() == 0, worker.log()
    finally:
        if worker is not None:
            worker.stop()
        server.stop()


def test_a_forked_worker_refuses_its_arguments_as_the_command_does(tmp_path: Path) -> None:
    server = ServerProcess(database_url="sqlite://", workdir=tmp_path)  # never started
    worker = WorkerProcess(server, tmp_path, "half", "--function", "scorer:score")
    assert isinstance(worker.process, ForkedProcess)
    assert worker.wait() == 2
    argv = ["--worker-id", "half", "--poll", "0.2", "--function", "scorer:score"]
    done = subprocess.run([str(ADWORKER), *argv], capture_output=True, text=True)
    assert done.returncode == 2
    assert "--function and --task go together" in worker.log()
    assert worker.log().strip() == done.stderr.strip()


def test_a_forked_worker_dies_of_sigkill(tmp_path: Path) -> None:
    """No handler of the fork server stands between the worker and a signal: SIGKILL is
    its end, as for the command (a Popen's returncode)."""
    server = ServerProcess(database_url="sqlite://", workdir=tmp_path)  # never started
    worker = WorkerProcess(server, tmp_path, "killed", "--idle-exit", "600")
    assert isinstance(worker.process, ForkedProcess)
    worker.signal(signal.SIGKILL)
    assert worker.wait() == -signal.SIGKILL


def test_a_ray_worker_is_started_by_command(tmp_path: Path) -> None:
    server = ServerProcess(database_url="sqlite://", workdir=tmp_path)  # never started
    worker = WorkerProcess(server, tmp_path, "ray", "--ray", "local", "--concurrency", "0")
    assert isinstance(worker.process, subprocess.Popen)
    assert worker.wait() == 2


def test_a_forked_adclient_answers_as_the_command_does(tmp_path: Path) -> None:
    """Its stdout and its stderr apart, its exit status, as ``subprocess.run`` gives them."""
    server = ServerProcess(database_url="sqlite://", workdir=tmp_path)  # never started
    missing = str(tmp_path / "missing.yaml")
    env = {**os.environ, "AD_SERVER_URL": server.url, "NO_COLOR": "1", "COLUMNS": "200"}
    for argv in (["submit", missing], ["--help"]):
        done = run_adclient(server, *argv)
        assert forked._server("adclient")._forkserver_pid is not None  # it ran forked
        command = subprocess.run([str(ADCLIENT), *argv], capture_output=True, text=True, env=env)
        assert (done.returncode, done.stdout, done.stderr) == (
            command.returncode,
            command.stdout,
            command.stderr,
        )
    assert done.returncode == 0 and "submit" in done.stdout
    refused = run_adclient(server, "submit", missing)
    assert refused.returncode != 0 and "missing.yaml" in refused.stderr
    assert refused.stdout == ""


def test_every_module_a_fork_server_preloads_is_installed() -> None:
    """A fork server skips a name that does not import, silently: a misspelt one would
    make every forked process import it again."""
    import importlib.util

    optional = {"uvicorn.loops.uvloop"}  # uvloop is not a dependency
    missing = [
        name
        for names in forked.PRELOAD.values()
        for name in names
        if name not in optional and importlib.util.find_spec(name) is None
    ]
    assert not missing, missing
