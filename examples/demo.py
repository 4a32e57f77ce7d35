"""``make demo``: the whole loop on this machine in a few minutes.

Starts ``adserver`` on a fresh SQLite file under ``var/demo/``, starts two
``adworker`` processes, submits ``examples/stand-up.yaml`` with ``adclient submit
--wait`` (progress bar), then prints the best design (params, score, URDF and image
paths) and the dashboard URL, and stops everything it started.

    .venv/bin/python examples/demo.py [--study FILE] [--workers N] [--keep-server]

``--keep-server`` leaves the server (and dashboard) up until Ctrl-C.
"""

from __future__ import annotations

import argparse
import math
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import httpx

from adclient import Client

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
VAR = ROOT / "var" / "demo"
PREFERRED_PORT = 8765


def free_port(preferred: int) -> int:
    for port in (preferred, 0):
        with socket.socket() as sock:
            try:
                sock.bind(("127.0.0.1", port))
            except OSError:
                continue
            return int(sock.getsockname()[1])
    raise RuntimeError("no free port")


def say(text: str) -> None:
    print(f"[demo] {text}", flush=True)


class Processes:
    """What the demo started, stopped in reverse order whatever happens."""

    def __init__(self) -> None:
        self.started: list[tuple[str, subprocess.Popen[bytes]]] = []

    def start(self, name: str, args: list[str], log: Path) -> subprocess.Popen[bytes]:
        with log.open("wb") as out:
            process = subprocess.Popen(
                args, cwd=ROOT, stdout=out, stderr=subprocess.STDOUT, start_new_session=True
            )
        self.started.append((name, process))
        return process

    def stop_all(self) -> None:
        for _name, process in reversed(self.started):
            if process.poll() is None:
                process.send_signal(signal.SIGTERM)
        for name, process in reversed(self.started):
            try:
                process.wait(timeout=60)
            except subprocess.TimeoutExpired:
                say(f"{name} did not stop on SIGTERM; killing it")
                process.kill()
                process.wait()
        self.started.clear()


def wait_healthy(url: str, process: subprocess.Popen[bytes], log: Path) -> None:
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        if process.poll() is not None:
            raise SystemExit(f"adserver exited early; see {log}:\n{log.read_text()[-2000:]}")
        try:
            if httpx.get(f"{url}/healthz", timeout=1.0).status_code == 200:
                return
        except httpx.TransportError:
            pass
        time.sleep(0.2)
    raise SystemExit(f"adserver did not answer at {url}; see {log}")


def show_best(client: Client, study_id: int, outdir: Path) -> None:
    study = client.study_info(study_id)
    best = client.best_trial(study_id)
    print()
    say(
        f"study {study.name!r}: {study.n_complete} complete, {study.n_failed} failed "
        f"of {study.max_trials}"
    )
    if best is None:
        say("no trial completed: see the worker logs under var/demo/")
        return
    outdir.mkdir(parents=True, exist_ok=True)
    paths: dict[str, Path] = {}
    for name in ("robot.urdf", "robot.png", "curve.json"):
        try:
            data = client.get_artifact(best, name)
        except Exception as exc:  # an artifact may be missing; the rest still shows
            say(f"could not fetch {name}: {exc}")
            continue
        paths[name] = outdir / name
        paths[name].write_bytes(data)
    print()
    print(f"Best design: trial #{best.number} (id {best.id}), score {best.value:.4f}")
    std = best.metrics.get("score_std")
    if std is not None and math.isfinite(std):
        print(f"  score spread over evaluation episodes: ± {std:.4f}")
    print("  searched params (the rest are fixed by the study file):")
    searched = _searched_names(study)
    for key, value in best.params.items():
        if key in searched:
            print(f"    {key} = {_show(value)}")
    for name, label in (("robot.urdf", "URDF"), ("robot.png", "image"), ("curve.json", "curve")):
        if name in paths:
            print(f"  {label}: {paths[name].relative_to(ROOT)}")
    print(f"  dashboard: {client.dashboard_url(study_id)}")


def _searched_names(study: Any) -> set[str]:
    from adclient.decode import searched_params
    from adclient.design import DesignSpace

    if isinstance(study.space, DesignSpace):
        return searched_params(study.space)
    return {param.name for param in study.space.params}


def _show(value: object) -> str:
    if isinstance(value, float):
        return f"{value:.4f}"
    if isinstance(value, list):
        return "(" + ", ".join(_show(item) for item in value) + ")"
    return str(value)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--study", type=Path, default=ROOT / "examples" / "stand-up.yaml")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--keep-server", action="store_true")
    args = parser.parse_args()

    if VAR.exists():
        shutil.rmtree(VAR)
    VAR.mkdir(parents=True)
    database = VAR / "studies.db"
    port = free_port(PREFERRED_PORT)
    url = f"http://127.0.0.1:{port}"
    processes = Processes()
    os.environ.setdefault("OMP_NUM_THREADS", "1")

    def on_signal(signum: int, _frame: object) -> None:
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, on_signal)
    try:
        say(f"starting adserver on {url} (database {database.relative_to(ROOT)})")
        server_log = VAR / "adserver.log"
        server = processes.start(
            "adserver",
            [
                str(BIN / "adserver"),
                "--host",
                "127.0.0.1",
                "--port",
                str(port),
                "--database-url",
                f"sqlite:///{database}",
                "--log-level",
                "warning",
            ],
            server_log,
        )
        wait_healthy(url, server, server_log)
        for k in range(1, args.workers + 1):
            say(f"starting worker demo-{k} (log var/demo/worker-{k}.log)")
            processes.start(
                f"worker demo-{k}",
                [
                    str(BIN / "adworker"),
                    "--server",
                    url,
                    "--worker-id",
                    f"demo-{k}",
                    "--poll",
                    "0.5",
                ],
                VAR / f"worker-{k}.log",
            )
        study = args.study.resolve()
        shown = study.relative_to(ROOT) if study.is_relative_to(ROOT) else study
        say(f"submitting {shown}; watch it live at {url}/")
        submitted = subprocess.run(
            [str(BIN / "adclient"), "--server", url, "submit", str(args.study), "--wait"],
            cwd=ROOT,
        )
        if submitted.returncode != 0:
            say(f"adclient submit failed (exit {submitted.returncode})")
            return submitted.returncode
        with Client(url) as client:
            studies = client.studies()
            if not studies:
                say("no study was created")
                return 1
            show_best(client, studies[-1].id, VAR / "best")
            if args.keep_server:
                say(f"server still up at {url}/ ; Ctrl-C to stop")
                while server.poll() is None:
                    time.sleep(1)
    except KeyboardInterrupt:
        say("interrupted")
        return 130
    finally:
        say("stopping the workers and the server")
        processes.stop_all()
    print(
        f"\nTo browse the results again: {BIN.relative_to(ROOT) / 'adserver'} --port {port} "
        f"--database-url sqlite:///{database.relative_to(ROOT)} and open {url}/"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
