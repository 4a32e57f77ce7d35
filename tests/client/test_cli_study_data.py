"""``adclient`` with free-text names, user attributes and ``delete``, against a real
``adserver`` (issue 16): names and attributes print as they are, never as rich markup."""

from __future__ import annotations

import csv
import io

from typer.testing import CliRunner, Result

from adclient import Client
from adclient.cli import app
from adclient.testing.servers import ServerProcess
from tests.client.cli_harness import failed_with, ok, run

BOX = {"type": "box", "params": [{"name": "x", "low": 0.0, "high": 1.0}]}
NAMES = ["Roboter-Entwurf 設計 v2", "stand up, long budget", "[bold]x[/bold]", "<img src=x>"]


def answered(answer: str, server_url: str, *args: str) -> Result:
    """The CLI with ``answer`` typed at its prompt."""
    environment = {"COLUMNS": "250", "AD_SERVER_URL": "", "AD_TOKEN": ""}
    return CliRunner().invoke(app, ["--server", server_url, *args], env=environment, input=answer)


def test_names_and_attributes_print_as_they_are(server: ServerProcess, client: Client) -> None:
    ids = [client.create_study(name=name, space=BOX).id for name in NAMES]
    listed = ok(run(server.url, "studies")).stdout
    for name in NAMES:
        assert name in listed
    study = client.get_study(ids[2])
    study.set_user_attr("note", "[red]not red[/red]")
    study.set_user_attr("budget", {"steps": 1000})
    shown = ok(run(server.url, "status", str(ids[2]))).stdout
    assert f"study {ids[2]}: [bold]x[/bold]" in shown
    assert "user attr note" in shown and "[red]not red[/red]" in shown
    assert "user attr budget" in shown and "steps=1000" in shown
    trial = study.ask()
    trial.set_user_attr("label", "[b]7[/b]")
    study.tell(trial, 0.5)
    table = ok(run(server.url, "trials", str(ids[2]))).stdout
    assert "x=" in table
    rows = list(csv.DictReader(io.StringIO(ok(run(server.url, "export", str(ids[2]))).stdout)))
    assert rows[0]["user_attrs_label"] == "[b]7[/b]"


def test_delete_asks_first_and_needs_force_while_workers_hold_leases(
    server: ServerProcess, client: Client
) -> None:
    study = client.create_study(
        name="[bold]doomed[/bold]",
        space=BOX,
        task={"name": "noop", "external": True},
        max_trials=3,
    )
    declined = answered("n\n", server.url, "delete", str(study.id))
    failed_with(declined, f"study {study.id} not deleted")
    assert "Delete study" in declined.stdout and "[bold]doomed[/bold]" in declined.stdout
    assert client.study_info(study.id).name == "[bold]doomed[/bold]"

    assert client.lease("w") is not None
    refused = run(server.url, "delete", str(study.id), "--yes")
    failed_with(refused, "leased by worker(s) 'w'")
    assert "--force" in refused.stderr
    ok(answered("y\n", server.url, "delete", str(study.id), "--force"))
    assert study.id not in [s.id for s in client.studies()]
    failed_with(run(server.url, "delete", str(study.id), "--yes"), f"study {study.id} not found")
