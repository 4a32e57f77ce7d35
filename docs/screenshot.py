"""Write docs/dashboard.png: a real ``adserver`` with a demo study, shot by headless Chromium.

The demo study is examples/stand-up.yaml (a managed design study) driven by three
scripted workers that lease jobs over HTTP like ``adworker`` does, but score each design
with a quick synthetic formula instead of training it, so the page fills in seconds.
A few trials fail, the last three stay leased (running), and each new best design gets
a robot.png rendered by the stand-up task's PyBullet software renderer, as a worker
uploads it.

    .venv/bin/python docs/screenshot.py [--out docs/dashboard.png] [--trials 120]
"""

from __future__ import annotations

import argparse
import io
import json
import math
import os
import random
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import httpx
import yaml

REPO = Path(__file__).resolve().parents[1]
ADSERVER = Path(sys.executable).with_name("adserver")
WORKERS = ("worker-a", "worker-b", "worker-c")


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def start_server(workdir: Path) -> tuple[subprocess.Popen[bytes], str]:
    port = free_port()
    url = f"http://127.0.0.1:{port}"
    log = (workdir / "adserver.log").open("wb")
    process = subprocess.Popen(
        [
            str(ADSERVER),
            "--host",
            "127.0.0.1",
            "--port",
            str(port),
            "--database-url",
            f"sqlite:///{workdir / 'studies.db'}",
            "--log-level",
            "warning",
        ],
        cwd=workdir,
        env={**os.environ, "AD_ARTIFACT_DIR": str(workdir / "artifacts")},
        stdout=log,
        stderr=subprocess.STDOUT,
    )
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        if process.poll() is not None:
            raise SystemExit(f"adserver exited:\n{(workdir / 'adserver.log').read_text()}")
        try:
            if httpx.get(f"{url}/healthz", timeout=1).status_code == 200:
                return process, url
        except httpx.TransportError:
            pass
        time.sleep(0.1)
    process.terminate()
    raise SystemExit("adserver did not start within 60 s")


def synthetic_score(params: dict[str, Any], rng: random.Random) -> float:
    """Rewards what makes the chain arch: both joint axes across the links and parallel
    to each other, a long body and feet of similar length."""
    across = (
        math.sin(params["b.joint.axis_theta"]) ** 2 * math.sin(params["c.joint.axis_theta"]) ** 2
    )
    parallel = math.cos(params["b.joint.axis_phi"] - params["c.joint.axis_phi"]) ** 2
    feet = 1.0 - abs(params["a.length"] - params["c.length"]) / 0.35
    return 0.5 * params["b.length"] * across * parallel * (0.6 + 0.4 * feet) + rng.gauss(0, 0.004)


def render_png(job: dict[str, Any], urdf: str, workdir: Path) -> bytes:
    """The job's design at rest through the stand-up task's PyBullet software renderer."""
    from PIL import Image

    from adclient.plugins import catalogue
    from adclient.schemas import Job
    from adworker.job_robots import decode_job

    path = workdir / "render.urdf"
    path.write_text(urdf)
    task = catalogue().task("stand-up")
    make_env = task.load_factory()
    env = make_env(
        design=decode_job(Job.model_validate(job)), urdf_path=path, options=task.options()
    )
    try:
        env.reset(seed=0)
        pixels = env.render_image(width=480, height=360)
    finally:
        env.close()
    buffer = io.BytesIO()
    Image.fromarray(pixels).save(buffer, format="PNG")
    return buffer.getvalue()


def curve(rng: random.Random, final: float) -> dict[str, list[float]]:
    steps = [i * 500 for i in range(1, 41)]
    values = [final * (1 - math.exp(-i / 8)) + rng.gauss(0, 0.01) for i in range(1, 41)]
    return {"steps": [float(s) for s in steps], "returns": values}


def run_demo(client: httpx.Client, trials: int, workdir: Path) -> int:
    spec = yaml.safe_load((REPO / "examples" / "stand-up.yaml").read_text())
    spec.update(
        name="stand-up-demo",
        proposer={"name": "tpe", "n_initial": 12, "seed": 3},
        max_trials=trials + 40,
        metadata={"note": "dashboard screenshot: scripted workers, synthetic scores"},
    )
    study = client.post("/api/v1/studies", json=spec).raise_for_status().json()
    rng = random.Random(7)
    best = -math.inf
    held: dict[str, dict[str, Any]] = {}
    told = 0
    while told < trials:
        worker = WORKERS[told % len(WORKERS)]
        for name in WORKERS:
            if name not in held:
                job = client.post("/api/v1/jobs/lease", json={"worker_id": name})
                job.raise_for_status()
                held[name] = job.json()
        job = held.pop(worker)
        client.post(f"/api/v1/trials/{job['trial_id']}/heartbeat", json={"worker_id": worker})
        if rng.random() < 0.06:
            body: dict[str, Any] = {
                "state": "failed",
                "worker_id": worker,
                "message": "simulation diverged: joint velocity above 1e3 rad/s",
            }
        else:
            value = synthetic_score(job["params"], rng)
            body = {"state": "complete", "value": value, "worker_id": worker}
        if body["state"] == "complete" and body["value"] > best:
            # A worker uploads while it holds the lease, before it tells.
            best = body["value"]
            trial_id = job["trial_id"]
            urdf = client.get(f"/api/v1/trials/{trial_id}/urdf").raise_for_status().text
            uploads = {
                "robot.png": (render_png(job, urdf, workdir), "image/png"),
                "robot.urdf": (urdf.encode(), "application/xml"),
                "curve.json": (json.dumps(curve(rng, best)).encode(), "application/json"),
            }
            for name, (content, content_type) in uploads.items():
                client.put(
                    f"/api/v1/trials/{trial_id}/artifacts/{name}",
                    params={"worker_id": worker},
                    content=content,
                    headers={"Content-Type": content_type},
                ).raise_for_status()
        client.post(f"/api/v1/trials/{job['trial_id']}/tell", json=body).raise_for_status()
        told += 1
    for name in WORKERS:  # each worker is busy with one more: leases show as running
        if name not in held:
            client.post("/api/v1/jobs/lease", json={"worker_id": name}).raise_for_status()
    return int(study["id"])


def shoot(url: str, out: Path, width: int, height: int) -> None:
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium is None:
        raise SystemExit("chromium is not installed: apt-get install -y chromium")
    with tempfile.TemporaryDirectory() as profile:
        subprocess.run(
            [
                chromium,
                "--headless",
                "--no-sandbox",
                "--disable-gpu",
                "--hide-scrollbars",
                f"--user-data-dir={profile}",
                f"--window-size={width},{height}",
                "--virtual-time-budget=6000",
                f"--screenshot={out}",
                url,
            ],
            check=True,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            timeout=120,
        )
    from PIL import Image

    with Image.open(out) as shot:  # a palette PNG: a third of the size, same look
        shot.convert("RGB").quantize(colors=256, dither=Image.Dither.NONE).save(out, optimize=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=REPO / "docs" / "dashboard.png")
    parser.add_argument("--trials", type=int, default=120, help="trials the workers finish")
    parser.add_argument("--width", type=int, default=1400)
    parser.add_argument("--height", type=int, default=2200)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        workdir = Path(tmp)
        process, url = start_server(workdir)
        try:
            headers = {"X-Activedesign-Client": "screenshot"}
            with httpx.Client(base_url=url, timeout=60, headers=headers) as client:
                study_id = run_demo(client, args.trials, workdir)
            args.out.parent.mkdir(parents=True, exist_ok=True)
            shoot(f"{url}/#/studies/{study_id}", args.out, args.width, args.height)
        finally:
            process.terminate()
            process.wait(timeout=15)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
