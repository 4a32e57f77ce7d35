"""``adclient trials``, ``best``, ``pareto``, ``ask``, ``tell`` and ``enqueue``: a
study's trials, and asking, telling and queueing them by hand."""

from __future__ import annotations

import json
from pathlib import Path

import typer
from rich.markup import escape

from adclient.cli.common import (
    app,
    compact_text,
    fail,
    friendly,
    front_table,
    get_settings,
    outcome_text,
    print_best,
    print_json,
    searched_keys,
    stderr_console,
    stdout_console,
    study_scope,
    trial_scope,
    trial_table,
)
from adclient.cli.files import FORCE_OPTION, save_trial_files
from adclient.importing import ImportFileError, load_json
from adclient.schemas import MAX_JSON_DEPTH, TrialState


@app.command()
@friendly
def trials(
    ctx: typer.Context,
    study_id: int = typer.Argument(..., metavar="ID"),
    state: TrialState | None = typer.Option(None, "--state", help="Only trials in this state."),
    everything: bool = typer.Option(
        False, "--all", help="Every param, not only those the study searched."
    ),
    as_json: bool = typer.Option(False, "--json", help="Print JSON."),
) -> None:
    """List a study's trials (of a design study, the params it searched)."""
    with get_settings(ctx).client() as client, study_scope(study_id):
        items = client.trials(study_id, state)
        searched = None if as_json or everything else searched_keys(client.study_info(study_id))
    if as_json:
        print_json(items)
        return
    title = f"study {study_id}: {len(items)} trials"
    stdout_console().print(trial_table(items, title=title, searched=searched))


@app.command()
@friendly
def best(
    ctx: typer.Context,
    study_id: int = typer.Argument(..., metavar="ID"),
    everything: bool = typer.Option(
        False, "--all", help="The whole design, not only the params the study searched."
    ),
    as_json: bool = typer.Option(False, "--json", help="Print JSON."),
    save: Path | None = typer.Option(
        None,
        "--save",
        help="Also download the best trial's files (URDF, images, curve...) into this folder.",
        file_okay=False,
    ),
    force: bool = FORCE_OPTION,
) -> None:
    """Show a study's best complete trial (of a design study, the params it searched).

    --save DIR also writes its files, as adclient files does."""
    with get_settings(ctx).client() as client, study_scope(study_id):
        trial = client.best_trial(study_id)
        searched = None if as_json or everything else searched_keys(client.study_info(study_id))
        if trial is None:
            fail(f"study {study_id} has no complete trial yet")
        if as_json:
            print_json(trial)
        else:
            print_best(stdout_console(), trial, searched)
        if save is not None:  # what was written goes to stderr beside JSON on stdout
            shown = stderr_console() if as_json else stdout_console()
            save_trial_files(client, trial, save, force=force, out=shown)


@app.command()
@friendly
def pareto(
    ctx: typer.Context,
    study_id: int = typer.Argument(..., metavar="ID"),
    as_json: bool = typer.Option(False, "--json", help="Print JSON."),
) -> None:
    """Show a study's Pareto front: its complete, feasible trials no other one dominates."""
    with get_settings(ctx).client() as client, study_scope(study_id):
        info = client.study_info(study_id)
        trials = client.pareto(study_id)
    if as_json:
        print_json(trials)
        return
    stdout_console().print(front_table(info, trials))


@app.command()
@friendly
def ask(
    ctx: typer.Context,
    study_id: int = typer.Argument(..., metavar="ID"),
    count: int = typer.Option(1, "--count", "-n", help="How many trials (1..64)."),
    as_json: bool = typer.Option(False, "--json", help="Print JSON."),
) -> None:
    """Ask a study for new trials to evaluate by hand."""
    with get_settings(ctx).client() as client, study_scope(study_id):
        items = client.ask(study_id, count)
    if as_json:
        print_json(items)
        return
    stdout_console().print(trial_table(items, title=f"study {study_id}: {len(items)} new trials"))


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
    with get_settings(ctx).client() as client, trial_scope(trial_id):
        trial = client.tell(
            trial_id,
            (value[0] if len(value) == 1 else value) if value else None,
            state="failed" if failed else "pruned" if pruned else "complete",
            message=message,
            metrics=metrics,
        )
    shown = ""
    if trial.value is not None or trial.values:
        shown = f": value{'s' if trial.values else ''} {outcome_text(trial)}"
    stdout_console().print(
        f"trial {trial.id} (study {trial.study_id}, #{trial.number}) {trial.state}{shown}"
    )


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
        given = load_json(params, deepest=MAX_JSON_DEPTH)
    except json.JSONDecodeError as exc:
        fail(f"--params is not JSON: {exc}", code=2)
    except ImportFileError as exc:
        fail(f"--params: {exc}", code=2)
    if not isinstance(given, dict):
        fail("--params must be a JSON object of param name -> value", code=2)
    with get_settings(ctx).client() as client, study_scope(study_id):
        trial = client.add_trials(study_id, [{"params": given, "skip_if_exists": skip_if_exists}])[
            0
        ]
    if as_json:
        print_json(trial)
        return
    stdout_console().print(
        f"trial {trial.id} (study {study_id}, #{trial.number}) {trial.state}: "
        f"{escape(compact_text(trial.params))}"
    )
