"""Checks that a command line or an environment a deployment file gives one of the
project's programs (``adserver``, ``adworker``) uses only options and ``AD_*`` variables the
real CLI and settings know: shared by the docker, Kubernetes and Slurm file tests."""

from __future__ import annotations

from typing import Any

import typer

from adservice.settings import Settings


def cli(program: str) -> Any:
    """The program's click command (typer builds it; typer may carry its own click)."""
    if program == "adserver":
        from adservice.cli import app
    elif program == "adworker":
        from adworker.cli import app
    else:
        raise AssertionError(f"{program!r} is not one of the project's programs")
    return typer.main.get_command(app)


def options(command: Any) -> set[str]:
    names = {"--help"}
    for param in command.params:
        names.update(param.opts)
        names.update(param.secondary_opts)
    return names


def envvars(command: Any) -> set[str]:
    found: set[str] = set()
    for param in command.params:
        value = getattr(param, "envvar", None)
        found.update([value] if isinstance(value, str) else value or [])
    return found


SETTINGS_VARIABLES = {f"AD_{name.upper()}" for name in Settings.model_fields}


def check_command(argv: list[str]) -> None:
    program, *args = argv
    command = cli(program)
    known = options(command)
    for arg in args:
        if arg.startswith("--"):
            assert arg.split("=", 1)[0] in known, f"{program} has no option {arg}"


def check_environment(program: str, env: dict[str, Any]) -> None:
    known = envvars(cli(program)) | (SETTINGS_VARIABLES if program == "adserver" else set())
    for name in env:
        if name.startswith("AD_"):
            assert name in known, f"{program} reads no {name} (knows {sorted(known)})"
