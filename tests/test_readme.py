"""The README's quick start runs as written: its REST lines against a real adserver
(create, ask, tell, delete), and its Python snippet against the same kind of server."""

from __future__ import annotations

import ast
import json
import re
import subprocess
import sys
from pathlib import Path

import httpx

from tests.servers import ServerProcess

README = Path(__file__).resolve().parents[1] / "README.md"


def block_after(marker: str) -> str:
    """The first fenced code block after ``marker`` in the README."""
    text = README.read_text().split(marker, 1)[1]
    return re.search(r"```\w*\n(.*?)```", text, re.S).group(1)  # type: ignore[union-attr]


def test_the_rest_quick_start_runs_as_written(live_server: ServerProcess) -> None:
    lines = block_after("**REST**").replace("\\\n", "").strip().splitlines()
    address = live_server.url.removeprefix("http://")
    answers = [
        subprocess.run(
            line.replace("localhost:8000", address) + " -w '\\n%{http_code}'",
            shell=True,
            capture_output=True,
            text=True,
            check=True,
        ).stdout.rsplit("\n", 1)
        for line in lines
    ]
    assert [code for _body, code in answers] == ["201", "200", "200", "204"]
    study, asked, told = (json.loads(body) for body, _code in answers[:3])
    assert study["id"] == 1 and asked["trials"][0]["id"] == 1
    assert told["state"] == "complete" and told["value"] == 0.25
    assert httpx.get(f"{live_server.url}/api/v1/studies/1").status_code == 404


def test_the_python_quick_start_runs_as_written(live_server: ServerProcess) -> None:
    code = block_after("**Python**").replace("http://127.0.0.1:8000", live_server.url)
    done = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        check=True,
    )
    best = ast.literal_eval(done.stdout.strip())  # the snippet prints best_params
    assert set(best) == {"x"} and -5 <= best["x"] <= 5
