"""``adclient import``, ``export`` and ``delete``: a study's trials in and out in
bulk, and the study gone with all of them."""

from __future__ import annotations

import sys
from pathlib import Path

import typer
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn

from adclient.cli.common import (
    api_error_message,
    app,
    exit_status,
    fail,
    friendly,
    get_settings,
    stderr_console,
    stdout_console,
    study_scope,
)
from adclient.errors import ApiError, Conflict
from adclient.importing import ImportFileError, read_import

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
        with file.open(encoding="utf-8", newline="") as stream:  # a cell's "\r" stays
            text = stream.read()
    except (OSError, UnicodeDecodeError) as exc:
        fail(f"cannot read {file}: {exc}")
    with get_settings(ctx).client() as client:
        space = None
        if study_id is not None:
            with study_scope(study_id):
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
            stderr_console().print(f"study {study_id} created")
        added = 0
        bar = Progress(
            TextColumn(f"study {study_id}"),
            BarColumn(),
            MofNCompleteColumn(),
            console=stderr_console(),
            transient=True,
        )
        with study_scope(study_id), bar as progress:
            task = progress.add_task("importing", total=len(plan.trials))
            for start in range(0, len(plan.trials), IMPORT_BATCH):
                batch = plan.trials[start : start + IMPORT_BATCH]
                try:
                    client.add_trials(study_id, batch)
                except ApiError as exc:
                    fail(
                        f"stopped after {added} of {len(plan.trials)} trials: "
                        f"{api_error_message(exc, client.url)}",
                        exit_status(exc),
                    )
                added += len(batch)
                progress.update(task, completed=added)
    left = f", {plan.left_out} unfinished left out" if plan.left_out else ""
    stdout_console().print(f"study {study_id}: {added} trials imported{left}")


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
    with get_settings(ctx).client() as client, study_scope(study_id):
        text = client.export(study_id, format)  # type: ignore[arg-type]
    if output is None:
        sys.stdout.write(text)
        return
    try:
        output.write_text(text, encoding="utf-8", newline="")
    except OSError as exc:
        fail(f"cannot write {output}: {exc.strerror or exc}")
    stderr_console().print(f"wrote study {study_id} to {escape(str(output))}")


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
    with get_settings(ctx).client() as client, study_scope(study_id):
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
    stdout_console().print(f"study {study_id} deleted")
