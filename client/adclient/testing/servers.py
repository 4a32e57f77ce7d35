"""Real ``adserver`` processes on free loopback ports: a database, real HTTP, tokens."""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import httpx

from adclient.testing.forked import ForkedProcess, ForkUnavailable, can_fork, run_adserver

ADSERVER = Path(sys.executable).with_name("adserver")
"""The ``adserver`` installed beside this interpreter: the harness runs it by command."""


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


@dataclass
class ServerProcess:
    """One running ``adserver``; ``restart()`` brings it back on the same port and database."""

    database_url: str
    workdir: Path
    env: dict[str, str] = field(default_factory=dict)
    port: int = field(default_factory=free_port)
    process: subprocess.Popen[bytes] | ForkedProcess | None = None
    """The running server: forked from preloaded imports where it can be
    (:mod:`.forked`), else started by command."""
    program: list[str] = field(default_factory=lambda: [str(ADSERVER)])
    """The command that runs adserver (a bench runs it through a launcher of its own)."""
    log_level: str = "warning"
    """``--log-level``: a test of what a start logs asks for the default, ``info``."""

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    @property
    def artifact_dir(self) -> Path:
        return self.workdir / "artifacts"

    @property
    def log_path(self) -> Path:
        return self.workdir / f"adserver-{self.port}.log"

    def start(self, timeout: float = 60.0) -> ServerProcess:
        env = {
            **os.environ,
            "AD_SWEEP_SECONDS": "0.5",
            "AD_ARTIFACT_DIR": str(self.artifact_dir),
            **self.env,
        }
        argv = [
            "--host",
            "127.0.0.1",
            "--port",
            str(self.port),
            "--database-url",
            self.database_url,
            "--log-level",
            self.log_level,
        ]
        self.process = None
        if self.program == [str(ADSERVER)] and can_fork(env):
            with contextlib.suppress(ForkUnavailable):
                self.process = ForkedProcess(argv, env=env, cwd=self.workdir, output=self.log_path)
        if self.process is None:
            with self.log_path.open("ab") as log:
                self.process = subprocess.Popen(
                    [*self.program, *argv],
                    cwd=self.workdir,
                    env=env,
                    stdout=log,
                    stderr=subprocess.STDOUT,
                )
        deadline = time.monotonic() + timeout
        with httpx.Client(verify=False) as poll:  # plain http: no CA bundle to load per poll
            while time.monotonic() < deadline:
                if self.process.poll() is not None:
                    raise RuntimeError(f"adserver exited early:\n{self.log()}")
                try:
                    if poll.get(f"{self.url}/healthz", timeout=1.0).status_code == 200:
                        return self
                except httpx.TransportError:
                    pass
                time.sleep(0.1)
        self.kill()  # not left running behind a fixture that never got it
        raise RuntimeError(f"adserver did not answer within {timeout}s:\n{self.log()}")

    def log(self) -> str:
        """The server's output so far, or why there is none: a forked server first runs
        the calling script's main module again (as ``multiprocessing`` does), so a script
        that starts one at import time ends it before it writes a line."""
        if self.log_path.exists():
            return self.log_path.read_text(errors="replace")
        return (
            f"(no output at {self.log_path}: it ended before writing any; a script that "
            'starts a server needs an `if __name__ == "__main__":` guard, as a forked '
            "server imports the script again)"
        )

    def kill(self) -> None:
        """SIGKILL: no chance to flush or clean up, as in a crash."""
        if self.process is not None and self.process.poll() is None:
            self.process.send_signal(signal.SIGKILL)
            self.process.wait()

    def stop(self) -> None:
        if self.process is not None and self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(timeout=15)
            except subprocess.TimeoutExpired:
                self.kill()

    def restart(self) -> ServerProcess:
        self.stop()
        return self.start()


SDK_HEADERS = {"X-Activedesign-Client": "test"}
"""What the SDK sends with every request; a raw client's POST without it (or a JSON
body) is refused 415, as a cross-site page's would be."""


def make_token(server: ServerProcess, role: str, name: str = "") -> str:
    """A new API token of ``role``, made as an operator would: ``adserver token create``
    (forked, as the server is, where it can be)."""
    argv = ["token", "create", "--role", role, "--database-url", server.database_url]
    argv += ["--name", name] if name else []
    with tempfile.TemporaryDirectory(prefix="adtoken-") as folder:
        output = Path(folder) / "out"
        code = run_adserver(argv, env=os.environ, cwd=server.workdir, output=output)
        text = output.read_text()
    if code != 0:
        raise RuntimeError(f"adserver token create exited {code}:\n{text}")
    return text.strip().splitlines()[-1]


def refused_at_start(command: list[str], code: int, **env: str) -> str:
    """Run a program that must stop at start: assert its exit ``code`` and that it said
    why without a traceback; returns what it wrote to stderr."""
    done = subprocess.run(
        command, env={**os.environ, **env}, capture_output=True, text=True, timeout=120
    )
    assert done.returncode == code, done.stderr
    assert "Traceback" not in done.stderr + done.stdout
    return done.stderr
