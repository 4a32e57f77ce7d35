"""``adclient``: the command line of the SDK.

Every command talks to the server named by ``--server`` (env ``AD_SERVER_URL``) with
the token of ``--token`` (env ``AD_TOKEN``); an https server with a private or
self-signed certificate needs ``--ca-bundle`` (env ``AD_CA_BUNDLE``). Listings are
rich tables, or JSON with ``--json``. Errors end with one line on stderr and exit
status 1 (2 for bad usage), never a traceback.
"""

from __future__ import annotations

import functools
import json
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NoReturn, TypeVar

import typer
import yaml
from pydantic import BaseModel
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from adclient import __version__
from adclient.client import Client, StudyHandle
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
from adclient.importing import ImportFileError, read_import
from adclient.schemas import BoxSpace, Study, Trial, TrialState

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


def _settings(ctx: typer.Context) -> Settings:
    settings = ctx.find_object(Settings)
    if settings is None:  # pragma: no cover - the callback always sets it
        settings = Settings(DEFAULT_SERVER, None)
    return settings


def _out() -> Console:
    return Console(highlight=False, soft_wrap=False)


def _err() -> Console:
    return Console(stderr=True, highlight=False)


def fail(message: str, code: int = 1) -> NoReturn:
    """End the command with one line on stderr."""
    _err().print(f"[bold red]error:[/] {escape(message)}", markup=True, highlight=False)
    raise typer.Exit(code)


def _api_message(exc: ApiError, server: str) -> str:
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
    """Turn SDK errors into a one-line message and exit status 1.

    The wrapped command takes the ``typer.Context`` (for the server URL in messages).
    """

    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        ctx = next((arg for arg in (*args, *kwargs.values()) if hasattr(arg, "find_object")), None)
        server = _settings(ctx).server if ctx is not None else DEFAULT_SERVER
        try:
            return func(*args, **kwargs)
        except ApiError as exc:
            fail(_api_message(exc, server))
        except KeyboardInterrupt:
            _err().print("interrupted")
            raise typer.Exit(130) from None

    return wrapper  # type: ignore[return-value]


@contextmanager
def _study_scope(study_id: int) -> Iterator[None]:
    """Name the study in a 404 ('study 7 not found') rather than echo the server."""
    try:
        yield
    except NotFound:
        fail(f"study {study_id} not found")


@contextmanager
def _trial_scope(trial_id: int) -> Iterator[None]:
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
    ctx.obj = Settings(server.rstrip("/"), token or None, str(ca_bundle) if ca_bundle else None)


# -- formatting ------------------------------------------------------------------------


def _num(value: float | None) -> str:
    return "" if value is None else f"{value:.6g}"


def _when(value: Any) -> str:
    return "" if value is None else value.strftime("%Y-%m-%d %H:%M:%S")


def _compact(value: Any, limit: int = 80) -> str:
    if isinstance(value, float):
        text = f"{value:.6g}"
    elif isinstance(value, dict):
        text = ", ".join(f"{key}={_compact(item, limit)}" for key, item in value.items())
    elif isinstance(value, str):
        text = value
    else:
        text = json.dumps(value, separators=(",", ":"), default=str)
    return text if len(text) <= limit else text[: limit - 1] + "…"


def _print_json(value: Any) -> None:
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


def _trial_table(trials: list[Trial], title: str | None = None) -> Table:
    table = Table(title=title)
    for column in ("#", "id", "state", "value", "worker", "attempts", "params"):
        table.add_column(column, justify="right" if column in {"#", "id", "value"} else "left")
    for trial in trials:
        table.add_row(
            str(trial.number),
            str(trial.id),
            _state_text(trial),
            _outcome_text(trial),
            escape(trial.worker_id or ""),
            str(trial.attempts),
            escape(_compact(trial.params, 100)),
        )
    return table


def _outcome_text(trial: Trial) -> str:
    """A trial's value, or its values (``0.41, 2.3``), marked when it breaks a
    constraint."""
    text = ", ".join(_num(v) for v in trial.values) if trial.values else _num(trial.value)
    return f"{text} [red](infeasible)[/red]" if trial.feasible is False else text


def _print_best(out: Console, trial: Trial) -> None:
    out.print(f"best trial #{trial.number} (id {trial.id}): value {_num(trial.value)}")
    out.print(_best_table(trial))


def _best_table(trial: Trial) -> Table:
    table = Table()
    table.add_column("param")
    table.add_column("value", overflow="fold")
    for name, value in trial.params.items():
        table.add_row(escape(name), escape(_compact(value, 200)))
    for name, value in trial.metrics.items():
        table.add_row(f"metric {name}", _num(value))
    return table


def _space_text(space: Any) -> str:
    """A box's params with their types and ranges (``n int [1, 64] log``, ``act in relu,
    tanh``); a design space by its type alone."""
    if not isinstance(space, BoxSpace):
        return str(space.type)
    parts = []
    for param in space.params:
        if param.type == "categorical":
            choices = ", ".join(_compact(choice) for choice in param.choices or [])
            parts.append(f"{param.name} in {{{choices}}}")
            continue
        text = f"{param.name} {param.type} [{_compact(param.low)}, {_compact(param.high)}]"
        text += " log" if param.log else ""
        text += f" step {_compact(param.step)}" if param.step is not None else ""
        parts.append(text)
    return "box: " + "; ".join(parts)


def _status_table(info: Study, dashboard: str) -> Table:
    table = Table(title=f"study {info.id}: {escape(info.name)}", show_header=False)
    table.add_column("field", style="bold")
    table.add_column("value", overflow="fold")
    budget = f"/{info.max_trials}" if info.max_trials is not None else ""
    rows = [
        ("state", info.state.value),
        ("direction", info.direction.value),
        ("managed", "yes" if info.managed else "no"),
        ("space", _space_text(info.space)),
        ("proposer", info.proposer.name),
        ("pruner", info.pruner.name),
        ("task", info.task.name if info.task is not None else ""),
        ("trials", f"{info.n_trials}{budget}"),
        ("queued", str(info.n_queued)),
        ("running", str(info.n_running)),
        ("complete", str(info.n_complete)),
        ("failed", str(info.n_failed)),
        ("pruned", str(info.n_pruned)),
        ("paused", str(info.n_paused)),
        ("best value", _num(info.best_value)),
        ("best trial", "" if info.best_trial_id is None else str(info.best_trial_id)),
        ("created", _when(info.created_at)),
        ("updated", _when(info.updated_at)),
        ("dashboard", dashboard),
        *((f"user attr {key}", _compact(value, 200)) for key, value in info.user_attrs.items()),
    ]
    for field, value in rows:
        table.add_row(escape(field), escape(value))
    return table


# -- commands --------------------------------------------------------------------------


def _read_study_file(path: Path) -> dict[str, Any]:
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        fail(f"cannot read {path}: {exc.strerror or exc}")
    try:
        data = json.loads(text) if path.suffix.lower() == ".json" else yaml.safe_load(text)
    except (ValueError, yaml.YAMLError) as exc:
        first_line = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        fail(f"cannot parse {path}: {first_line}")
    if not isinstance(data, dict):
        fail(f"{path} must hold a mapping with a study body (name, space, ...)")
    return data


@app.command()
@friendly
def submit(
    ctx: typer.Context,
    study_file: Path = typer.Argument(..., help="YAML or JSON file with a study body."),
    wait: bool = typer.Option(False, "--wait", "-w", help="Follow the study until it finishes."),
    poll: float = typer.Option(2.0, "--poll", min=0.01, help="Seconds between polls with --wait."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="Print only the study id."),
) -> None:
    """Create a study from STUDY_FILE; print its id and dashboard URL."""
    body = _read_study_file(study_file)
    settings = _settings(ctx)
    with settings.client() as client:
        study = client.create_study(body)
        info = study.cached_info
        if quiet:
            typer.echo(str(study.id))
        else:
            out = _out()
            out.print(f"study {study.id} created: {escape(info.name)}")
            out.print(f"dashboard: {study.dashboard_url}")
        if not wait:
            return
        info = _follow(study, poll)
        if quiet:
            return
        out = _out()
        out.print(
            f"study {study.id} {info.state.value}: {info.n_complete} complete, "
            f"{info.n_failed} failed, {info.n_pruned} pruned"
        )
        if len(info.directions) > 1:  # no single best trial: the front, as `pareto` shows it
            front = study.best_trials
            out.print(_front_table(info, front) if front else "no complete trial")
            return
        best = study.best_trial
        if best is None:
            out.print("no complete trial")
        else:
            _print_best(out, best)


def _follow(study: StudyHandle, poll: float) -> Study:
    """Poll with a progress bar of finished trials until the study is finished."""
    info = study.cached_info
    with Progress(
        TextColumn(f"study {study.id}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("best {task.fields[best]}"),
        TimeElapsedColumn(),
        console=_err(),
        transient=False,
    ) as progress:
        bar = progress.add_task("trials", total=info.max_trials, completed=0, best="-")

        def update(current: Study) -> None:
            progress.update(
                bar,
                completed=current.n_complete + current.n_failed + current.n_pruned,
                total=current.max_trials,
                best=_num(current.best_value) or "-",
            )

        try:
            return study.wait(poll=poll, on_update=update)
        except KeyboardInterrupt:
            progress.stop()
            _err().print(f"stopped waiting; study {study.id} keeps running")
            raise typer.Exit(130) from None


@app.command()
@friendly
def studies(
    ctx: typer.Context,
    as_json: bool = typer.Option(False, "--json", help="Print JSON."),
) -> None:
    """List the studies."""
    with _settings(ctx).client() as client:
        items = client.studies()
    if as_json:
        _print_json(items)
        return
    table = Table(title="studies")
    columns = ("id", "name", "direction", "state", "trials", "complete", "failed", "pruned")
    for column in (*columns, "best"):
        left = column in {"name", "direction", "state"}
        table.add_column(column, justify="left" if left else "right")
    for info in items:
        budget = f"/{info.max_trials}" if info.max_trials is not None else ""
        table.add_row(
            str(info.id),
            escape(info.name),
            info.direction.value,
            info.state.value,
            f"{info.n_trials}{budget}",
            str(info.n_complete),
            str(info.n_failed),
            str(info.n_pruned),
            _num(info.best_value),
        )
    _out().print(table)


@app.command()
@friendly
def status(
    ctx: typer.Context,
    study_id: int = typer.Argument(..., metavar="ID"),
    as_json: bool = typer.Option(False, "--json", help="Print JSON."),
) -> None:
    """Show one study: state, trial counts, best value."""
    with _settings(ctx).client() as client, _study_scope(study_id):
        info = client.study_info(study_id)
        dashboard = client.dashboard_url(study_id)
    if as_json:
        _print_json(info)
        return
    _out().print(_status_table(info, dashboard))


@app.command()
@friendly
def trials(
    ctx: typer.Context,
    study_id: int = typer.Argument(..., metavar="ID"),
    state: TrialState | None = typer.Option(None, "--state", help="Only trials in this state."),
    as_json: bool = typer.Option(False, "--json", help="Print JSON."),
) -> None:
    """List a study's trials."""
    with _settings(ctx).client() as client, _study_scope(study_id):
        items = client.trials(study_id, state)
    if as_json:
        _print_json(items)
        return
    _out().print(_trial_table(items, title=f"study {study_id}: {len(items)} trials"))


@app.command()
@friendly
def best(
    ctx: typer.Context,
    study_id: int = typer.Argument(..., metavar="ID"),
    as_json: bool = typer.Option(False, "--json", help="Print JSON."),
) -> None:
    """Show a study's best complete trial."""
    with _settings(ctx).client() as client, _study_scope(study_id):
        trial = client.best_trial(study_id)
    if trial is None:
        fail(f"study {study_id} has no complete trial yet")
    if as_json:
        _print_json(trial)
        return
    _print_best(_out(), trial)


@app.command()
@friendly
def pareto(
    ctx: typer.Context,
    study_id: int = typer.Argument(..., metavar="ID"),
    as_json: bool = typer.Option(False, "--json", help="Print JSON."),
) -> None:
    """Show a study's Pareto front: its complete, feasible trials no other one dominates."""
    with _settings(ctx).client() as client, _study_scope(study_id):
        info = client.study_info(study_id)
        trials = client.pareto(study_id)
    if as_json:
        _print_json(trials)
        return
    _out().print(_front_table(info, trials))


def _front_table(info: Study, trials: list[Trial]) -> Table:
    """A study's Pareto front (``trials``) under a title naming its objectives."""
    names = ", ".join(
        f"{name} ({direction.value[:3]})"
        for name, direction in zip(info.objective_names, info.directions, strict=True)
    )
    title = f"study {info.id}: {len(trials)} trials on the Pareto front of {names}"
    return _trial_table(trials, title=title)


@app.command()
@friendly
def ask(
    ctx: typer.Context,
    study_id: int = typer.Argument(..., metavar="ID"),
    count: int = typer.Option(1, "--count", "-n", help="How many trials (1..64)."),
    as_json: bool = typer.Option(False, "--json", help="Print JSON."),
) -> None:
    """Ask a study for new trials to evaluate by hand."""
    with _settings(ctx).client() as client, _study_scope(study_id):
        items = client.ask(study_id, count)
    if as_json:
        _print_json(items)
        return
    _out().print(_trial_table(items, title=f"study {study_id}: {len(items)} new trials"))


@app.command()
@friendly
def tell(
    ctx: typer.Context,
    trial_id: int = typer.Argument(..., metavar="TRIAL"),
    value: list[float] | None = typer.Argument(
        None,
        help="The trial's score, or one value per objective (omit with --failed).",
        show_default=False,
    ),
    failed: bool = typer.Option(False, "--failed", help="Report the trial as failed."),
    pruned: bool = typer.Option(
        False, "--pruned", help="End the trial as pruned (VALUE optional: else its last report)."
    ),
    message: str | None = typer.Option(None, "--message", "-m", help="Why it failed."),
    metric: list[str] = typer.Option([], "--metric", help="Extra metric NAME=NUMBER (repeatable)."),
) -> None:
    """Tell a trial's result: a VALUE (several for a study of several objectives),
    --failed with a --message, or --pruned."""
    if failed and (value or pruned):
        fail("give either a VALUE or --failed, not both", code=2)
    if not failed and not pruned and not value:
        fail("missing VALUE (or --failed for a failed trial)", code=2)
    if pruned and value and len(value) > 1:
        fail("--pruned takes at most one VALUE", code=2)
    metrics: dict[str, float] = {}
    for item in metric:
        name, sep, number = item.partition("=")
        try:
            if not sep or not name:
                raise ValueError
            metrics[name] = float(number)
        except ValueError:
            fail(f"--metric wants NAME=NUMBER, got {item!r}", code=2)
    with _settings(ctx).client() as client, _trial_scope(trial_id):
        trial = client.tell(
            trial_id,
            (value[0] if len(value) == 1 else value) if value else None,
            state="failed" if failed else "pruned" if pruned else "complete",
            message=message,
            metrics=metrics,
        )
    shown = ""
    if trial.value is not None or trial.values:
        shown = f": value{'s' if trial.values else ''} {_outcome_text(trial)}"
    _out().print(f"trial {trial.id} (study {trial.study_id}, #{trial.number}) {trial.state}{shown}")


@app.command()
@friendly
def enqueue(
    ctx: typer.Context,
    study_id: int = typer.Argument(..., metavar="ID"),
    params: str = typer.Option(..., "--params", "-p", help="The params as JSON: '{\"x\": 0.5}'."),
    skip_if_exists: bool = typer.Option(
        False, "--skip-if-exists", help="Answer an existing trial of the same params instead."
    ),
    as_json: bool = typer.Option(False, "--json", help="Print JSON."),
) -> None:
    """Queue PARAMS in a study: its next ask (or a worker) takes them before proposing."""
    try:
        given = json.loads(params)
    except json.JSONDecodeError as exc:
        fail(f"--params is not JSON: {exc}", code=2)
    if not isinstance(given, dict):
        fail("--params must be a JSON object of param name -> value", code=2)
    with _settings(ctx).client() as client, _study_scope(study_id):
        trial = client.add_trials(study_id, [{"params": given, "skip_if_exists": skip_if_exists}])[
            0
        ]
    if as_json:
        _print_json(trial)
        return
    _out().print(
        f"trial {trial.id} (study {study_id}, #{trial.number}) {trial.state}: "
        f"{escape(_compact(trial.params))}"
    )


IMPORT_BATCH = 500
"""Trials per request of ``adclient import`` (each request stores all of its or none)."""


@app.command("import")
@friendly
def import_trials(
    ctx: typer.Context,
    file: Path = typer.Argument(..., exists=True, dir_okay=False, help="An export or a CSV."),
    study_id: int | None = typer.Option(
        None, "--study", help="Add to this study (a CSV needs one); default: a new study."
    ),
    name: str | None = typer.Option(None, "--name", help="The new study's name."),
    skip_unfinished: bool = typer.Option(
        False, "--skip-unfinished", help="Leave out unfinished trials (default: enqueue them)."
    ),
) -> None:
    """Import trials: the JSON `adclient export` writes (a new study like the exported one,
    or --study ID), or a CSV of param columns and a value column (into --study ID)."""
    format = "csv" if file.suffix.lower() == ".csv" else "json"
    if format == "csv" and study_id is None:
        fail("a CSV has no space to make a study from: give --study ID", code=2)
    try:
        text = file.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        fail(f"cannot read {file}: {exc}")
    with _settings(ctx).client() as client:
        space = None
        if study_id is not None:
            with _study_scope(study_id):
                space = client.study_info(study_id).space.model_dump(mode="json")
        try:
            plan = read_import(
                text, format=format, space=space, queue_unfinished=not skip_unfinished
            )
        except ImportFileError as exc:
            fail(f"{file}: {exc}")
        if study_id is None:
            if plan.study is None:
                fail(f"{file} names no study: give --study ID", code=2)
            body = plan.study | ({"name": name} if name else {})
            study_id = client.create_study(body).id
            _err().print(f"study {study_id} created")
        added = 0
        bar = Progress(
            TextColumn(f"study {study_id}"),
            BarColumn(),
            MofNCompleteColumn(),
            console=_err(),
            transient=True,
        )
        with _study_scope(study_id), bar as progress:
            task = progress.add_task("importing", total=len(plan.trials))
            for start in range(0, len(plan.trials), IMPORT_BATCH):
                batch = plan.trials[start : start + IMPORT_BATCH]
                try:
                    client.add_trials(study_id, batch)
                except ApiError as exc:
                    fail(
                        f"stopped after {added} of {len(plan.trials)} trials: "
                        f"{_api_message(exc, client.url)}"
                    )
                added += len(batch)
                progress.update(task, completed=added)
    left = f", {plan.left_out} unfinished left out" if plan.left_out else ""
    _out().print(f"study {study_id}: {added} trials imported{left}")


@app.command()
@friendly
def export(
    ctx: typer.Context,
    study_id: int = typer.Argument(..., metavar="ID"),
    format: str = typer.Option("csv", "--format", "-f", help="csv or json."),
    output: Path | None = typer.Option(None, "--output", "-o", help="File (default: stdout)."),
) -> None:
    """Export a study's trials as CSV or JSON."""
    if format not in {"csv", "json"}:
        fail(f"--format must be csv or json, not {format!r}", code=2)
    with _settings(ctx).client() as client, _study_scope(study_id):
        text = client.export(study_id, format)  # type: ignore[arg-type]
    if output is None:
        sys.stdout.write(text)
        return
    try:
        output.write_text(text, encoding="utf-8")
    except OSError as exc:
        fail(f"cannot write {output}: {exc.strerror or exc}")
    _err().print(f"wrote study {study_id} to {escape(str(output))}")


@app.command()
@friendly
def delete(
    ctx: typer.Context,
    study_id: int = typer.Argument(..., metavar="ID"),
    force: bool = typer.Option(
        False, "--force", help="Also while workers hold leases on its trials (cancelled)."
    ),
    yes: bool = typer.Option(False, "--yes", "-y", help="Do not ask for confirmation."),
) -> None:
    """Delete a study with its trials, reports and artifacts: its owner or an admin."""
    with _settings(ctx).client() as client, _study_scope(study_id):
        info = client.study_info(study_id)
        question = (
            f"Delete study {study_id} ({info.name}) with its {info.n_trials} trials "
            "and their artifacts?"
        )
        if not yes and not typer.confirm(question):
            fail(f"study {study_id} not deleted")
        try:
            client.delete_study(study_id, force=force)
        except Conflict as exc:
            fail(f"conflict: {exc.message} (adclient delete --force cancels the leases)")
    _out().print(f"study {study_id} deleted")


def main() -> None:
    """Console-script entry point."""
    app()


if __name__ == "__main__":  # pragma: no cover
    main()
