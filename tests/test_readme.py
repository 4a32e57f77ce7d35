"""The README's quick start runs as written: its REST lines against a real adserver
(create, ask, tell, delete), and its Python snippet against the same kind of server."""

from __future__ import annotations

import ast
import json
import re
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import httpx
import pytest

from adclient.testing.servers import ServerProcess

README = Path(__file__).resolve().parents[1] / "README.md"


def block_after(marker: str) -> str:
    """The first fenced code block after ``marker`` in the README."""
    text = README.read_text().split(marker, 1)[1]
    return re.search(r"```\w*\n(.*?)```", text, re.S).group(1)  # type: ignore[union-attr]


@pytest.fixture
def first_start(
    server_factory: Callable[..., ServerProcess], empty_database_url: str
) -> ServerProcess:
    """A server's first start, as the quick start's: on a database nothing has touched
    (it migrates the schema at start)."""
    return server_factory(database_url=empty_database_url)


def test_the_rest_quick_start_runs_as_written(first_start: ServerProcess) -> None:
    lines = block_after("**REST**").replace("\\\n", "").strip().splitlines()
    address = first_start.url.removeprefix("http://")
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
    assert httpx.get(f"{first_start.url}/api/v1/studies/1").status_code == 404


def test_the_python_quick_start_runs_as_written(first_start: ServerProcess) -> None:
    code = block_after("**Python**").replace("http://127.0.0.1:8000", first_start.url)
    done = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        check=True,
    )
    best = ast.literal_eval(done.stdout.strip())  # the snippet prints best_params
    assert set(best) == {"x"} and -5 <= best["x"] <= 5


def test_the_exit_status_table_is_what_the_programs_use() -> None:
    """Each status the README gives a program is the constant that program exits with
    (the behaviour itself: tests/client/test_cli.py and the worker's tests)."""
    from adclient.cli import common
    from adworker import worker

    rows = [
        [cell.strip() for cell in line.strip("|").split("|")]
        for line in README.read_text().splitlines()
        if re.match(r"\| \d+ \|", line)
    ]
    table = {int(status): (client, work, server) for status, client, work, server in rows}
    assert table[common.EXIT_REFUSED][0].startswith("the server refused the request")
    assert table[common.EXIT_USAGE][0].startswith("a usage error")
    assert table[common.EXIT_NO_SERVER][0].startswith("no server")
    assert table[common.EXIT_TOKEN][0].startswith("the server refused the token")
    assert table[common.EXIT_INTERRUPTED][0].startswith("interrupted")
    assert table[worker.EXIT_OK][1].startswith("stopped as asked")
    assert table[worker.EXIT_SETUP][1].startswith("the worker could not start")
    assert table[worker.EXIT_AUTH][1].startswith("the server refused the token")
    assert (
        len({common.EXIT_REFUSED, common.EXIT_USAGE, common.EXIT_NO_SERVER, common.EXIT_TOKEN}) == 4
    )
