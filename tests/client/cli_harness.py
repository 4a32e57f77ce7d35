"""What the CLI tests share: the CLI run in process (typer's CliRunner), with the checks of
a clean success and a clean failure, and a study file written for ``submit``."""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path

import yaml
from typer.testing import CliRunner, Result

from adclient.cli import app


def run(server_url: str, *args: str, env: dict[str, str] | None = None) -> Result:
    """Invoke the CLI in-process; wide columns so rich tables do not wrap the values."""
    runner = CliRunner()
    environment = {"COLUMNS": "250", "AD_SERVER_URL": "", "AD_TOKEN": "", **(env or {})}
    argv = ["--server", server_url, *args] if server_url else list(args)
    return runner.invoke(app, argv, env=environment)


def ok(result: Result) -> Result:
    assert result.exit_code == 0, (result.stdout, result.stderr, result.exception)
    return result


def failed_with(result: Result, message: str, code: int = 1) -> None:
    """A clean failure: the message on stderr, one line, no traceback."""
    assert result.exit_code == code, (result.stdout, result.stderr, result.exception)
    assert isinstance(result.exception, SystemExit)
    assert message in result.stderr
    assert "Traceback" not in result.stderr + result.stdout
    assert len(result.stderr.strip().splitlines()) == 1, result.stderr


def write_study(tmp_path: Path, body: Mapping[str, object], suffix: str = ".yaml") -> Path:
    path = tmp_path / f"study{suffix}"
    text = json.dumps(body) if suffix == ".json" else yaml.safe_dump(body)
    path.write_text(text)
    return path
