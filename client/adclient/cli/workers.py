"""``adclient workers``: the workers a server has seen and the tasks they serve; and the
note a managed study gets when no recent worker serves its task (a plugin missing on
the workers' path is the likeliest reason a study waits at 0 of N)."""

from __future__ import annotations

from dataclasses import dataclass
from datetime import UTC, datetime

import typer
from rich.markup import escape
from rich.table import Table

from adclient.calls import ServerCalls
from adclient.cli.common import app, friendly, get_settings, print_json, stdout_console
from adclient.schemas import Study, WorkerInfo

RECENT_SECONDS = 90.0
"""A worker seen this recently is serving: an idle adworker asks for work at least every
30 s."""


def _age(worker: WorkerInfo, now: datetime) -> float:
    seen = worker.last_seen_at
    seen = seen if seen.tzinfo is not None else seen.replace(tzinfo=UTC)
    return (now - seen).total_seconds()


def serves(worker: WorkerInfo, task: str) -> bool:
    return worker.tasks is None or task in worker.tasks


@dataclass(frozen=True)
class Serving:
    """How many recently seen workers serve a study's task, and that said for a person."""

    count: int
    text: str


def serving(client: ServerCalls, info: Study) -> Serving | None:
    """For a running managed study: how many recently seen workers serve its task, or,
    when none does, what to start; None for a study no worker runs."""
    if info.task is None or info.state.value != "running":
        return None
    now = datetime.now(UTC)
    recent = [w for w in client.workers() if _age(w, now) <= RECENT_SECONDS]
    task = info.task.name
    count = sum(serves(w, task) for w in recent)
    if count:
        text = f"{count} serving task {task!r}, seen in the last {RECENT_SECONDS:g} s"
        return Serving(count, text)
    others = f" ({len(recent)} other workers serve other tasks)" if recent else ""
    how = (
        f"adworker --function MODULE:FUNCTION --task {task}"
        if info.task.external
        else "adworker (with the task's plugin importable)"
    )
    text = (
        f"none serving task {task!r} seen in the last {RECENT_SECONDS:g} s{others}: "
        f"the study waits for one; start {how}, and see `adclient workers`"
    )
    return Serving(0, text)


@app.command()
@friendly
def workers(
    ctx: typer.Context,
    as_json: bool = typer.Option(False, "--json", help="Print JSON."),
) -> None:
    """List the workers the server has seen, newest first, with the tasks they serve."""
    with get_settings(ctx).client() as client:
        items = client.workers()
    if as_json:
        print_json(items)
        return
    now = datetime.now(UTC)
    table = Table(title=f"workers: {len(items)}")
    for column in ("worker", "last seen", "tasks", "trial", "done", "failed"):
        table.add_column(column, justify="right" if column in {"done", "failed"} else "left")
    for worker in items:
        table.add_row(
            escape(worker.worker_id),
            f"{_age(worker, now):.0f} s ago",
            escape(", ".join(worker.tasks)) if worker.tasks is not None else "any",
            "" if worker.current_trial_id is None else str(worker.current_trial_id),
            str(worker.jobs_done),
            str(worker.jobs_failed),
        )
    stdout_console().print(table)
