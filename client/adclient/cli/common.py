"""What every ``adclient`` command shares: the Typer app and its callback (server, token,
CA bundle), the console helpers, ``fail``, the one-line messages for SDK errors
(``friendly``), the study and trial scopes, and the tables of trials."""

from __future__ import annotations

import functools
import json
import os
import sys
from collections import Counter
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NoReturn, TypeVar
from urllib.parse import urlsplit

import typer
from pydantic import BaseModel
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from adclient import __version__
from adclient.client import Client
from adclient.design import DesignSpace
from adclient.errors import (
    ApiError,
    Conflict,
    Forbidden,
    Invalid,
    NotFound,
    PayloadTooLarge,
    Unauthorized,
    Unavailable,
)
from adclient.schemas import Study, Trial, TrialState

DEFAULT_SERVER = "http://127.0.0.1:8000"
CLI_RETRIES = 3
"""Fewer retries than the SDK's default: a person is waiting for the answer."""

app = typer.Typer(
    name="adclient",
    help="Submit and follow activedesign studies; ask and tell trials by hand.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

F = TypeVar("F", bound=Callable[..., Any])

CA_BUNDLE_OPTION = typer.Option(
    None,
    "--ca-bundle",
    envvar="AD_CA_BUNDLE",
    exists=True,
    dir_okay=False,
    help="CA certificates (PEM) to check an https server against.",
)
"""Shared with ``adworker``."""


@dataclass
class Settings:
    server: str
    token: str | None
    ca_bundle: str | None = None

    def client(self) -> Client:
        verify = self.ca_bundle or True
        return Client(self.server, self.token, retries=CLI_RETRIES, backoff=0.1, verify=verify)


def get_settings(ctx: typer.Context) -> Settings:
    settings = ctx.find_object(Settings)
    if settings is None:  # pragma: no cover - the callback always sets it
        settings = Settings(DEFAULT_SERVER, None)
    return settings


UNBOUNDED_WIDTH = 100_000
"""The width of a console that is not a terminal (a pipe, a file) and has no
``COLUMNS``: tables as wide as their cells and lines never broken, where a terminal's
width would be 80 columns."""


def _sized(console: Console) -> Console:
    if not console.is_terminal and "COLUMNS" not in os.environ:
        console.width = UNBOUNDED_WIDTH
    return console


def stdout_console() -> Console:
    return _sized(Console(highlight=False, soft_wrap=False))


def stderr_console() -> Console:
    return _sized(Console(stderr=True, highlight=False))


EXIT_REFUSED = 1
"""The server refused the request (invalid, not found, conflict, too large), or the
command failed otherwise."""
EXIT_USAGE = 2
"""A usage error: an unknown option or a missing argument (Click's own status), a study
file that cannot be read, a server URL without a scheme."""
EXIT_NO_SERVER = 3
"""The server could not be reached, did not answer, or answered that it is unavailable:
worth retrying later."""
EXIT_TOKEN = 4
"""The server refused the token (none, unknown or revoked: 401) or its role (403), as
adworker's refused token."""
EXIT_INTERRUPTED = 130


def exit_status(exc: ApiError) -> int:
    """The exit status of a command that ended in ``exc`` (the README's "Exit statuses")."""
    if isinstance(exc, Unavailable):
        return EXIT_NO_SERVER
    if isinstance(exc, Unauthorized | Forbidden):
        return EXIT_TOKEN
    return EXIT_REFUSED


def fail(message: str, code: int = EXIT_REFUSED) -> NoReturn:
    """End the command with one line on stderr (one line of a pipe or file, whatever its
    length; a terminal wraps it at its width)."""
    console = stderr_console()
    console.print(
        f"[bold red]error:[/] {escape(message)}",
        markup=True,
        highlight=False,
        soft_wrap=not console.is_terminal,
    )
    raise typer.Exit(code)


def api_error_message(exc: ApiError, server: str) -> str:
    if isinstance(exc, Unavailable):
        if exc.status_code is None and exc.code == "unreachable":
            return f"cannot reach server at {server}"
        if exc.status_code is None:
            return f"no answer from server at {server}"
        return f"server at {server} is unavailable: {exc.message} (HTTP {exc.status_code})"
    if isinstance(exc, Unauthorized):
        return f"unauthorized: {exc.message} (give a token with --token or AD_TOKEN)"
    if isinstance(exc, Forbidden):
        return f"forbidden: {exc.message}"
    if isinstance(exc, Invalid):
        return f"invalid request: {exc.message}"
    if isinstance(exc, Conflict):
        return f"conflict: {exc.message}"
    if isinstance(exc, PayloadTooLarge):
        return f"too large: {exc.message}"
    if isinstance(exc, NotFound):
        return f"not found: {exc.message}"
    return str(exc)


def friendly(func: F) -> F:
    """Turn SDK errors into a one-line message and an exit status (``exit_status``).

    The wrapped command takes the ``typer.Context`` (for the server URL in messages).
    """

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        ctx = next((arg for arg in (*args, *kwargs.values()) if hasattr(arg, "find_object")), None)
        server = get_settings(ctx).server if ctx is not None else DEFAULT_SERVER
        try:
            return func(*args, **kwargs)
        except ApiError as exc:
            fail(api_error_message(exc, server), exit_status(exc))
        except KeyboardInterrupt:
            stderr_console().print("interrupted")
            raise typer.Exit(EXIT_INTERRUPTED) from None

    return wrapper  # type: ignore[return-value]


@contextmanager
def study_scope(study_id: int) -> Iterator[None]:
    """Name the study in a 404 ('study 7 not found') rather than echo the server."""
    try:
        yield
    except NotFound:
        fail(f"study {study_id} not found")


@contextmanager
def trial_scope(trial_id: int) -> Iterator[None]:
    try:
        yield
    except NotFound:
        fail(f"trial {trial_id} not found")


def _version(value: bool) -> None:
    if value:
        typer.echo(f"adclient {__version__}")
        raise typer.Exit()


@app.callback()
def _main(
    ctx: typer.Context,
    server: str = typer.Option(
        DEFAULT_SERVER, "--server", "-s", envvar="AD_SERVER_URL", help="Server base URL."
    ),
    token: str | None = typer.Option(
        None, "--token", envvar="AD_TOKEN", help="Bearer token.", show_default=False
    ),
    ca_bundle: Path | None = CA_BUNDLE_OPTION,
    version: bool = typer.Option(
        False, "--version", callback=_version, is_eager=True, help="Print the version."
    ),
) -> None:
    _check_server_url(server)
    ctx.obj = Settings(server.rstrip("/"), token or None, str(ca_bundle) if ca_bundle else None)


def _check_server_url(server: str) -> None:
    """A usage error for a server that is no http(s) URL (``-s 127.0.0.1:8000``), which
    would otherwise read as a server that does not answer."""
    parts = urlsplit(server.strip())
    if parts.scheme in ("http", "https") and parts.netloc:
        return
    given = f"--server (or AD_SERVER_URL) {server!r}"
    if "://" not in server:
        fail(f"{given} has no scheme: give http://{server.strip()} (or https://)", EXIT_USAGE)
    fail(f"{given} is not an http:// or https:// URL with a host", EXIT_USAGE)


# -- formatting ------------------------------------------------------------------------


def number_text(value: float | None) -> str:
    return "" if value is None else f"{value:.6g}"


def compact_text(value: Any, limit: int = 80) -> str:
    if isinstance(value, float):
        text = f"{value:.6g}"
    elif isinstance(value, dict):
        text = ", ".join(f"{key}={compact_text(item, limit)}" for key, item in value.items())
    elif isinstance(value, str):
        text = value
    else:
        text = json.dumps(value, separators=(",", ":"), default=str)
    return text if len(text) <= limit else text[: limit - 1] + "…"


def print_json(value: Any) -> None:
    data: Any
    if isinstance(value, BaseModel):
        data = value.model_dump(mode="json")
    elif isinstance(value, list):
        data = [item.model_dump(mode="json") for item in value]
    else:
        data = value
    sys.stdout.write(json.dumps(data, indent=2) + "\n")


def _state_text(trial: Trial) -> str:
    """The state, and whether the study's owner handed the trial over (enqueued, or an
    evaluation added) rather than its proposer making it."""
    source = trial.info.get("source")
    return (
        f"{trial.state.value} ({source})" if source in ("enqueued", "added") else trial.state.value
    )


def trial_table(
    trials: list[Trial], title: str | None = None, searched: set[str] | None = None
) -> Table:
    """The trials a row each (their searched params, all when ``searched`` is None); a
    ``message`` column (why a trial failed or was pruned) when any of them has one."""
    table = Table(title=title)
    messages = any(trial.message for trial in trials)
    columns = ("#", "id", "state", "value", "worker", "attempts", "params")
    for column in columns + (("message",) if messages else ()):
        table.add_column(column, justify="right" if column in {"#", "id", "value"} else "left")
    for trial in trials:
        row = [
            str(trial.number),
            str(trial.id),
            _state_text(trial),
            outcome_text(trial),
            escape(trial.worker_id or ""),
            str(trial.attempts),
            escape(compact_text(shown_params(trial, searched), 100)),
        ]
        if messages:
            row.append(escape(compact_text(trial.message or "", 120)))
        table.add_row(*row)
    return table


def failure_lines(trials: list[Trial], most: int = 3) -> list[str]:
    """Why a study's trials failed, the commonest reasons first: ``2 x the function
    returned value = nan``."""
    reasons = Counter(
        trial.message or "(no message)" for trial in trials if trial.state == TrialState.failed
    )
    common = reasons.most_common(most)
    lines = [f"{count} x {compact_text(reason, 200)}" for reason, count in common]
    if len(reasons) > most:
        others = len(reasons) - most
        lines.append(f"... and {others} other reasons (adclient trials ID --state failed)")
    return lines


def outcome_text(trial: Trial) -> str:
    """A trial's value, or its values (``0.41, 2.3``), marked when it breaks a
    constraint."""
    text = (
        ", ".join(number_text(v) for v in trial.values)
        if trial.values
        else number_text(trial.value)
    )
    return f"{text} [red](infeasible)[/red]" if trial.feasible is False else text


def searched_keys(info: Study) -> set[str] | None:
    """The params keys a design study searched (``decode.searched_params``); None for a
    box or template study, whose every param is searched."""
    if not isinstance(info.space, DesignSpace):
        return None
    from adclient.decode import searched_params

    return searched_params(info.space)


def shown_params(trial: Trial, searched: set[str] | None) -> dict[str, Any]:
    """A trial's params, only the searched ones when ``searched`` says which."""
    if searched is None:
        return dict(trial.params)
    return {key: value for key, value in trial.params.items() if key in searched}


def print_best(out: Console, trial: Trial, searched: set[str] | None = None) -> None:
    """The best trial: its searched params (all of them when ``searched`` is None) and
    metrics, and how many params the study file fixed or a tie derived."""
    out.print(f"best trial #{trial.number} (id {trial.id}): value {number_text(trial.value)}")
    shown = shown_params(trial, searched)
    table = Table()
    table.add_column("param")
    table.add_column("value", overflow="fold")
    for name, value in shown.items():
        table.add_row(escape(name), escape(compact_text(value, 200)))
    for name, value in trial.metrics.items():
        table.add_row(f"metric {name}", number_text(value))
    out.print(table)
    hidden = len(trial.params) - len(shown)
    if hidden:
        out.print(
            f"searched params only: {hidden} more are fixed by the study file or follow "
            f"from these (ties, mirrors, catalogues); adclient best {trial.study_id} --all "
            "shows the whole design"
        )


def front_table(info: Study, trials: list[Trial]) -> Table:
    """A study's Pareto front (``trials``) under a title naming its objectives."""
    names = ", ".join(
        f"{name} ({direction.value[:3]})"
        for name, direction in zip(info.objective_names, info.directions, strict=True)
    )
    title = f"study {info.id}: {len(trials)} trials on the Pareto front of {names}"
    return trial_table(trials, title=title)
