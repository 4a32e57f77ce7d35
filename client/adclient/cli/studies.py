"""``adclient submit``, ``studies``, ``status`` and ``stop``: create a study, follow it
(``submit --wait`` and ``status --wait``), list the studies, show one, stop one."""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any

import typer
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from adclient.cli.common import (
    EXIT_INTERRUPTED,
    app,
    compact_text,
    fail,
    failure_lines,
    friendly,
    front_table,
    get_settings,
    number_text,
    print_best,
    print_json,
    searched_keys,
    stderr_console,
    stdout_console,
    study_scope,
)
from adclient.cli.study_file import read_study_file
from adclient.cli.suggest import unknown_field_hints, with_hints
from adclient.cli.workers import serving
from adclient.client import StudyHandle
from adclient.errors import Invalid
from adclient.schemas import BoxSpace, Study, StudySpread, StudyState

ONE_DESIGN = "one design: nothing searched, each trial a repeat on its own seed"
"""How ``status`` and ``submit --wait`` name a study whose space searches nothing."""


def _when(value: Any) -> str:
    return "" if value is None else value.strftime("%Y-%m-%d %H:%M:%S")


def _space_text(space: Any) -> str:
    """A box's params with their types and ranges (``n int [1, 64] log``, ``act in relu,
    tanh``), a template's the same; a design space by its type alone."""
    if not isinstance(space, BoxSpace) or not space.params:
        return str(space.type)
    parts = []
    for param in space.params:
        if param.type == "categorical":
            choices = ", ".join(compact_text(choice) for choice in param.choices or [])
            parts.append(f"{param.name} in {{{choices}}}")
            continue
        text = f"{param.name} {param.type} [{compact_text(param.low)}, {compact_text(param.high)}]"
        text += " log" if param.log else ""
        text += f" step {compact_text(param.step)}" if param.step is not None else ""
        parts.append(text)
    return f"{space.type}: " + "; ".join(parts)  # box, or template (a box with a robot)


def _proposal_rows(info: Study) -> list[tuple[str, str]]:
    """A study whose proposals fail: how often in a row, until when workers skip it, why;
    one whose latest ask fell back to Sobol points: why, and how many so far."""
    rows = []
    if info.proposal_failures:
        rows += [
            (
                "proposals",
                f"failing ({info.proposal_failures} in a row); workers skip the study until "
                f"{_when(info.proposal_retry_at)} UTC",
            ),
            ("proposal error", info.proposal_error or ""),
        ]
    if info.proposal_fallback_reason:
        rows.append(
            (
                "fallback",
                f"the latest ask fell back to Sobol points ({info.proposal_fallbacks} "
                f"candidate{'' if info.proposal_fallbacks == 1 else 's'} so far): "
                f"{info.proposal_fallback_reason}",
            )
        )
    return rows


def spread_rows(spread: StudySpread) -> list[tuple[str, str]]:
    """Each objective's spread over the complete trials (a study of one design: its
    repeats), a row each: ``spread of value``, ``5 repeats: mean 0.41, std 0.03, ...``."""
    rows = []
    for objective in spread.objectives:
        text = "no complete repeat yet"
        if objective.n:
            numbers = ("mean", "std", "min", "median", "max")
            text = f"{objective.n} repeat{'' if objective.n == 1 else 's'}: " + ", ".join(
                f"{name} {number_text(getattr(objective, name)) or '-'}" for name in numbers
            )
        rows.append((f"spread of {objective.name}", text))
    return rows


def _status_table(info: Study, dashboard: str, spread: StudySpread | None) -> Table:
    table = Table(title=f"study {info.id}: {escape(info.name)}", show_header=False)
    table.add_column("field", style="bold")
    table.add_column("value", overflow="fold")
    budget = f"/{info.max_trials}" if info.max_trials is not None else ""
    rows = [
        ("state", info.state.value),
        ("direction", info.direction.value),
        ("managed", "yes" if info.managed else "no"),
        ("space", _space_text(info.space) + (f" ({ONE_DESIGN})" if info.fixed else "")),
        ("proposer", "none (one design)" if info.fixed else info.proposer.name),
        ("pruner", info.pruner.name),
        ("task", info.task.name if info.task is not None else ""),
        ("trials", f"{info.n_trials}{budget}"),
        ("queued", str(info.n_queued)),
        ("running", str(info.n_running)),
        ("complete", str(info.n_complete)),
        ("failed", str(info.n_failed)),
        ("pruned", str(info.n_pruned)),
        ("paused", str(info.n_paused)),
        ("best value", number_text(info.best_value)),
        ("best trial", "" if info.best_trial_id is None else str(info.best_trial_id)),
        *(spread_rows(spread) if spread is not None else ()),
        ("created", _when(info.created_at)),
        ("updated", _when(info.updated_at)),
        ("dashboard", dashboard),
        *_proposal_rows(info),
        *((f"user attr {key}", compact_text(value, 200)) for key, value in info.user_attrs.items()),
    ]
    for field, value in rows:
        table.add_row(escape(field), escape(value))
    return table


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
    body = read_study_file(study_file)
    settings = get_settings(ctx)
    with settings.client() as client:
        try:
            study = client.create_study(body)
        except Invalid as exc:  # an unknown field gets its closest valid name
            message = with_hints(exc.message, unknown_field_hints(body))
            fail(f"invalid request: {message}")
        info = study.cached_info
        if quiet:
            typer.echo(str(study.id))
        else:
            out = stdout_console()
            out.print(f"study {study.id} created: {escape(info.name)}")
            out.print(f"dashboard: {study.dashboard_url}")
        if wait:
            follow_to_end(study, poll, quiet=quiet)


def follow_to_end(study: StudyHandle, poll: float, *, quiet: bool = False) -> Study:
    """``submit --wait`` and ``status --wait``: a progress bar until the study ends, then
    (unless ``quiet``) how it ended: its counts, why trials failed, and its best design,
    the spread of its repeats or its Pareto front."""
    info = _follow(study, poll)
    if not quiet:
        _print_end(study, info)
    return info


def _print_end(study: StudyHandle, info: Study) -> None:
    out = stdout_console()
    out.print(
        f"study {study.id} {info.state.value}: {info.n_complete} complete, "
        f"{info.n_failed} failed, {info.n_pruned} pruned"
    )
    if info.n_failed:
        out.print("why trials failed:")
        for line in failure_lines(study.get_trials("failed")):
            out.print(f"  {escape(line)}")
    if info.fixed:  # no best of repeats of one design: how they spread
        out.print(f"{ONE_DESIGN}:")
        for field, text in spread_rows(study.spread):
            out.print(f"  {escape(field)}: {text}")
        return
    if len(info.directions) > 1:  # no single best trial: the front, as `pareto` shows it
        front = study.best_trials
        out.print(front_table(info, front) if front else "no complete trial")
        return
    best = study.best_trial
    if best is None:
        out.print("no complete trial")
    else:
        print_best(out, best, searched_keys(info))


WORKERS_CHECK_SECONDS = 10.0
"""How long ``--wait`` (submit, status) sees no trial start before it checks for a serving
worker."""


def _follow(study: StudyHandle, poll: float) -> Study:
    """Poll with a progress bar of finished trials until the study is finished."""
    info = study.cached_info
    with Progress(
        TextColumn(f"study {study.id}"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("best {task.fields[best]}"),
        TimeElapsedColumn(),
        console=stderr_console(),
        transient=False,
    ) as progress:
        bar = progress.add_task("trials", total=info.max_trials, completed=0, best="-")
        started, checked = time.monotonic(), False

        def update(current: Study) -> None:
            nonlocal checked
            finished = current.n_complete + current.n_failed + current.n_pruned
            progress.update(
                bar,
                completed=finished,
                total=current.max_trials,
                best=number_text(current.best_value) or "-",
            )
            idle = finished == 0 and current.n_running == 0
            if idle and not checked and time.monotonic() - started >= WORKERS_CHECK_SECONDS:
                checked = True  # once: say why a study waits at 0 of N, if no worker serves it
                workers = serving(study.client, current)
                if workers is not None and workers.serving == 0:
                    progress.console.print(f"[yellow]no worker:[/yellow] {escape(workers.text)}")

        try:
            progress.console.print(
                f"following study {study.id} until it ends (Ctrl-C stops following; "
                "the study keeps running)"
            )
            return study.wait(poll=poll, on_update=update)
        except KeyboardInterrupt:
            progress.stop()
            stderr_console().print(f"stopped waiting; study {study.id} keeps running")
            raise typer.Exit(EXIT_INTERRUPTED) from None


@app.command()
@friendly
def studies(
    ctx: typer.Context,
    as_json: bool = typer.Option(False, "--json", help="Print JSON."),
) -> None:
    """List the studies."""
    with get_settings(ctx).client() as client:
        items = client.studies()
    if as_json:
        print_json(items)
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
            info.state.value + (" (proposals failing)" if info.proposal_failures else ""),
            f"{info.n_trials}{budget}",
            str(info.n_complete),
            str(info.n_failed),
            str(info.n_pruned),
            number_text(info.best_value),
        )
    stdout_console().print(table)


@app.command()
@friendly
def status(
    ctx: typer.Context,
    study_id: int = typer.Argument(..., metavar="ID"),
    as_json: bool = typer.Option(False, "--json", help="Print JSON."),
    wait: bool = typer.Option(
        False, "--wait", "-w", help="Follow the study until it ends, as submit --wait does."
    ),
    poll: float = typer.Option(2.0, "--poll", min=0.01, help="Seconds between polls with --wait."),
) -> None:
    """Show one study: state, trial counts, best value.

    With --wait, follow it until it ends (a progress bar), then show how it ended, as
    submit --wait does."""
    with get_settings(ctx).client() as client, study_scope(study_id):
        if wait:
            ended = follow_to_end(client.get_study(study_id), poll, quiet=as_json)
            if as_json:
                print_json(ended)
            return
        info = client.study_info(study_id)
        dashboard = client.dashboard_url(study_id)
        workers = None if as_json else serving(client, info)
        spread = client.spread(study_id) if info.fixed and not as_json else None
    if as_json:
        print_json(info)
        return
    table = _status_table(info, dashboard, spread)
    if workers is not None:
        table.add_row("workers", escape(workers.text))
    stdout_console().print(table)


@app.command()
@friendly
def stop(
    ctx: typer.Context,
    study_id: int = typer.Argument(..., metavar="ID"),
    as_json: bool = typer.Option(False, "--json", help="Print JSON."),
) -> None:
    """Stop a study: no new trials are proposed or leased.

    Its owner or an admin may; its queued trials end as failed, the running ones may
    still be told."""
    with get_settings(ctx).client() as client, study_scope(study_id):
        before = client.study_info(study_id)
        info = client.stop_study(study_id)
    if as_json:
        print_json(info)
        return
    counts = f"{info.n_complete} complete, {info.n_failed} failed, {info.n_pruned} pruned"
    out = stdout_console()
    if before.state != StudyState.running:
        out.print(f"study {study_id} is already {before.state.value}: nothing to stop ({counts})")
        return
    out.print(f"study {study_id} stopped: no new trials are proposed or leased; {counts}")
    if before.n_queued:
        out.print(f'{before.n_queued} queued trials ended as failed ("study stopped")')
    if info.n_running:
        out.print(f"{info.n_running} running trials may still be told")


@app.command()
@friendly
def note(
    ctx: typer.Context,
    study_id: int = typer.Argument(..., metavar="STUDY"),
    text: str | None = typer.Argument(
        None, metavar="[TEXT|-]", help="The new text ('-': read from stdin; '': remove it)."
    ),
    trial: int | None = typer.Option(
        None, "--trial", metavar="N", help="Trial number N's note, not the study's."
    ),
    as_json: bool = typer.Option(False, "--json", help="Print JSON."),
) -> None:
    """Show a study's note, or trial N's; with TEXT, replace it (its owner or an admin).

    The note is the dashboard's: free text, at most 10000 characters."""
    if text == "-":
        text = sys.stdin.read()
    subject = f"study {study_id}" if trial is None else f"trial {trial} of study {study_id}"
    with get_settings(ctx).client() as client, study_scope(study_id):
        found = None if trial is None else client.trial_by_number(study_id, trial)
        if trial is not None and found is None:
            fail(f"study {study_id} has no trial {trial}")
        if text is None:
            saved = client.study_note(study_id) if found is None else client.trial_note(found)
        elif found is None:
            saved = client.set_study_note(study_id, text)
        else:
            saved = client.set_trial_note(found, text)
    if as_json:
        print_json(saved)
        return
    if text is not None:
        said = f"{len(saved.text)} characters" if saved.text else "removed"
        stdout_console().print(f"note of {escape(subject)} saved: {said}")
        return
    if not saved.text:
        stdout_console().print(f"{escape(subject)} has no note")
        return
    sys.stdout.write(saved.text if saved.text.endswith("\n") else f"{saved.text}\n")
