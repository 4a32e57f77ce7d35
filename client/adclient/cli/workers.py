"""``adclient workers``: the workers a server has seen and the tasks and learners they
serve; and the note a managed study gets when no recent worker serves its task and
learner (a plugin missing on the workers' path is the likeliest reason a study waits
at 0 of N)."""

from __future__ import annotations

from datetime import UTC, datetime

import typer
from rich.markup import escape
from rich.table import Table

from adclient.calls import ServerCalls
from adclient.cli.common import app, friendly, get_settings, print_json, stdout_console
from adclient.schemas import Study, StudyServing, WorkerInfo


def _age(worker: WorkerInfo, now: datetime) -> float:
    seen = worker.last_seen_at
    seen = seen if seen.tzinfo is not None else seen.replace(tzinfo=UTC)
    return (now - seen).total_seconds()


def serving(client: ServerCalls, info: Study) -> StudyServing | None:
    """For a running managed study, the server's word on how many recently seen workers
    serve its task and learner, or what to start when none does (``GET
    /studies/{id}/serving``, the rule the dashboard shows too); None for a study no
    worker runs."""
    if info.task is None or info.state.value != "running":
        return None
    return client.serving(info.id)


@app.command()
@friendly
def workers(
    ctx: typer.Context,
    as_json: bool = typer.Option(False, "--json", help="Print JSON."),
) -> None:
    """List the workers the server has seen, newest first, with the tasks and learners
    they serve."""
    with get_settings(ctx).client() as client:
        items = client.workers()
    if as_json:
        print_json(items)
        return
    now = datetime.now(UTC)
    table = Table(title=f"workers: {len(items)}")
    for column in ("worker", "state", "last seen", "tasks", "learners", "trial", "done", "failed"):
        table.add_column(column, justify="right" if column in {"done", "failed"} else "left")
    for worker in items:
        table.add_row(
            escape(worker.worker_id),
            worker.state or "unknown",  # null: a server older than the field
            f"{_age(worker, now):.0f} s ago",
            escape(", ".join(worker.tasks)) if worker.tasks is not None else "any",
            escape(", ".join(worker.learners)) if worker.learners is not None else "any",
            "" if worker.current_trial_id is None else str(worker.current_trial_id),
            str(worker.jobs_done),
            str(worker.jobs_failed),
        )
    stdout_console().print(table)
