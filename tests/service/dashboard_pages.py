"""What the dashboard's browser tests share: the scripts that read a rendered page
(canvas pixels, the table), the colours the charts draw with, and studies seeded
through the API (over HTTP or in-process: anything with httpx's ``get`` and ``post``)."""

from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Any

import httpx
from PIL import Image

PARAMS = ("x", "y", "z")
EXAMPLES = Path(__file__).resolve().parents[2] / "examples"

MANAGED_BOX = {
    "name": "dashboard-box",
    "direction": "maximize",
    "space": {
        "type": "box",
        "params": [{"name": name, "low": 0.0, "high": 1.0} for name in PARAMS],
    },
    "proposer": {"name": "random", "seed": 11},
    "task": {"name": "noop", "external": True},
    "max_trials": 40,
}

STUDY_PAGE_READY = "document.querySelector('.study')?.dataset.ready === 'true'"

COUNT_PIXELS = """
((selector, rgb, tolerance) => {
  const canvas = document.querySelector(selector);
  const data = canvas.getContext('2d').getImageData(0, 0, canvas.width, canvas.height).data;
  let count = 0;
  for (let i = 0; i < data.length; i += 4) {
    if (data[i + 3] === 0) continue;
    if (rgb === null || (Math.abs(data[i] - rgb[0]) <= tolerance
        && Math.abs(data[i + 1] - rgb[1]) <= tolerance
        && Math.abs(data[i + 2] - rgb[2]) <= tolerance)) count++;
  }
  return count;
})
"""
DISPLAY = "((selector) => getComputedStyle(document.querySelector(selector)).display)"
ORANGE = [234, 88, 12]  # the best-so-far curve
BLUE = [37, 99, 235]  # the score points

# A WebGL canvas read as a person sees it: copied onto a 2D canvas. "Robot" pixels are
# coloured ones (the URDF's link colours, lit); background and grid are near-grey.
SNAPSHOT = """
((selector) => {
  const source = document.querySelector(selector);
  const copy = document.createElement('canvas');
  copy.width = source.width;
  copy.height = source.height;
  const ctx = copy.getContext('2d');
  ctx.drawImage(source, 0, 0);
  return ctx.getImageData(0, 0, copy.width, copy.height).data;
})
"""
ROBOT_PIXELS = f"""
((selector) => {{
  const data = {SNAPSHOT}(selector);
  let count = 0;
  for (let i = 0; i < data.length; i += 4) {{
    if (Math.max(data[i], data[i + 1], data[i + 2])
        - Math.min(data[i], data[i + 1], data[i + 2]) > 40) count++;
  }}
  return count;
}})
"""
KEEP_PIXELS = f"""
((selector, name) => {{ (window.kept ??= {{}})[name] = {SNAPSHOT}(selector); return true; }})
"""
CHANGED_PIXELS = f"""
((selector, name) => {{
  const data = {SNAPSHOT}(selector);
  const kept = window.kept[name];
  let count = 0;
  for (let i = 0; i < data.length; i += 4) {{
    if (Math.abs(data[i] - kept[i]) + Math.abs(data[i + 1] - kept[i + 1])
        + Math.abs(data[i + 2] - kept[i + 2]) > 30) count++;
  }}
  return count;
}})
"""

TABLE_NUMBERS = (
    "[...document.querySelectorAll('[data-trials] tbody tr[data-trial-id]')]"
    ".map(row => parseInt(row.cells[0].textContent))"
)
TABLE_STATES = (
    "[...document.querySelectorAll('[data-trials] tbody tr[data-trial-id]')]"
    ".map(row => row.cells[1].textContent.trim())"
)


def sign_in(browser: Any, url: str, token: str) -> None:
    """Open the study page at ``url`` of a server with auth on and sign in with ``token``
    through the page's form (``browser``: a :class:`~tests.service.chromium.Chromium`),
    until the page is ready."""
    browser.navigate(url)
    browser.wait_for("!document.querySelector('[data-auth]').hidden")
    browser.evaluate(
        f"(() => {{ const form = document.querySelector('[data-auth] form');"
        f" form.elements.token.value = {json.dumps(token)}; form.requestSubmit(); }})()"
    )
    browser.wait_for(STUDY_PAGE_READY)


def png(width: int, height: int) -> bytes:
    image = Image.new("RGB", (width, height), (40, 120, 200))
    for x in range(width):
        image.putpixel((x, height // 2), (250, 200, 0))
    buffer = io.BytesIO()
    image.save(buffer, format="PNG")
    return buffer.getvalue()


def score(params: dict[str, float]) -> float:
    return params["x"] + 2 * params["y"] - params["z"]


def lease(http: httpx.Client, worker: str) -> dict[str, Any]:
    response = http.post("/api/v1/jobs/lease", json={"worker_id": worker})
    assert response.status_code == 200, response.text
    return dict(response.json())


def tell(http: httpx.Client, trial_id: int, **body: Any) -> None:
    response = http.post(f"/api/v1/trials/{trial_id}/tell", json=body)
    assert response.status_code == 200, response.text


def upload(
    http: httpx.Client, trial_id: int, name: str, content: bytes, content_type: str, worker: str
) -> None:
    """As a worker does: while it holds the trial's lease, before it tells."""
    response = http.put(
        f"/api/v1/trials/{trial_id}/artifacts/{name}",
        params={"worker_id": worker},
        content=content,
        headers={"Content-Type": content_type, "X-Activedesign-Client": "test"},
    )
    assert response.status_code == 201, response.text


def seed_curves(http: Any) -> tuple[int, list[int]]:
    """A study of 4 trials, asked: the first reports nothing, the second reports steps
    300, 100 and 200 (out of order) and completes, the third reports and is pruned, the
    fourth reports and runs. Returns the study's id and the 4 trial ids."""
    space = {"type": "box", "params": [{"name": "x", "low": 0, "high": 1}]}
    created = http.post("/api/v1/studies", json={"name": "curves", "space": space})
    study = created.raise_for_status().json()["id"]
    asked = http.post(f"/api/v1/studies/{study}/ask", json={"count": 4}).raise_for_status()
    silent, done, pruned, running = (t["id"] for t in asked.json()["trials"])
    for trial_id, step, value in (
        (done, 300, 0.5),
        (done, 100, 0.1),
        (done, 200, 0.3),
        (pruned, 100, -0.2),
        (running, 100, 0.05),
    ):
        answer = http.post(f"/api/v1/trials/{trial_id}/report", json={"step": step, "value": value})
        assert answer.status_code == 200, answer.text
    http.post(f"/api/v1/trials/{done}/tell", json={"value": 0.6}).raise_for_status()
    http.post(f"/api/v1/trials/{pruned}/tell", json={"state": "pruned"}).raise_for_status()
    return study, [silent, done, pruned, running]


def seed_mixed_study(http: httpx.Client) -> dict[str, Any]:
    """A managed study: 8 complete and 2 failed trials told by two workers, one trial
    leased by worker-1 and two asked (running), and an image and a URDF on each
    complete trial (uploaded before its tell, as workers do)."""
    study = http.post("/api/v1/studies", json=MANAGED_BOX).raise_for_status().json()
    values: dict[int, float] = {}
    done = {"worker-1": 0, "worker-2": 0}
    failed = {"worker-1": 0, "worker-2": 0}
    for i in range(10):
        worker = f"worker-{i % 2 + 1}"
        job = lease(http, worker)
        if i in (3, 6):
            tell(http, job["trial_id"], state="failed", worker_id=worker, message="diverged")
            failed[worker] += 1
        else:
            value = score(job["params"])
            upload(http, job["trial_id"], "robot.png", png(64, 48), "image/png", worker)
            urdf = b'<robot name="r"><link name="a"/></robot>'
            upload(http, job["trial_id"], "robot.urdf", urdf, "application/xml", worker)
            tell(http, job["trial_id"], value=value, worker_id=worker)
            values[job["number"]] = value
            done[worker] += 1
    held = lease(http, "worker-1")
    asked = http.post(f"/api/v1/studies/{study['id']}/ask", json={"count": 2}).raise_for_status()
    best = http.get(f"/api/v1/studies/{study['id']}/best").raise_for_status().json()
    return {
        "study": study,
        "values": values,
        "best": best,
        "held": held,
        "asked": asked.json()["trials"],
        "done": done,
        "failed": failed,
    }
