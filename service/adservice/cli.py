"""``adserver``: run the activedesign HTTP service, and manage its API tokens."""

from __future__ import annotations

import ipaddress
import logging
import socket
from pathlib import Path
from typing import Any

import typer
from pydantic import ValidationError

from adclient.devices import device_problem
from adservice.settings import Settings

app = typer.Typer(add_completion=False, help="The activedesign server.")
tokens = typer.Typer(add_completion=False, help="API tokens (bearer tokens with a role).")
app.add_typer(tokens, name="token")

DATABASE_OPTION = typer.Option(
    None, "--database-url", help="SQLAlchemy URL (default: AD_DATABASE_URL or ./activedesign.db)."
)


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        try:
            return ipaddress.ip_address(socket.gethostbyname(host)).is_loopback
        except OSError:
            return False


def _settings(**given: Any) -> Settings:
    """``Settings`` from the environment, with the options given on the command line
    taking precedence (so an option's default is its ``AD_`` variable's value)."""
    try:
        return Settings(**{name: value for name, value in given.items() if value is not None})
    except ValidationError as error:
        problems = "; ".join(
            f"{'.'.join(map(str, item['loc'])) or 'settings'}: {item['msg']}"
            for item in error.errors()
        )
        typer.echo(f"adserver: invalid settings: {problems}", err=True)
        raise typer.Exit(2) from None


@app.callback(invoke_without_command=True)
def serve(
    ctx: typer.Context,
    host: str | None = typer.Option(
        None, "--host", help="Address to bind (default: AD_HOST or 127.0.0.1)."
    ),
    port: int | None = typer.Option(
        None, "--port", help="Port to bind (default: AD_PORT or 8000)."
    ),
    database_url: str | None = DATABASE_OPTION,
    insecure: bool = typer.Option(
        False, "--insecure", help="Allow a non-loopback address without authentication."
    ),
    log_level: str | None = typer.Option(
        None, "--log-level", help="debug, info, warning... (default: AD_LOG_LEVEL or info)."
    ),
    ssl_certfile: Path | None = typer.Option(
        None, "--ssl-certfile", help="Serve HTTPS with this PEM certificate (AD_SSL_CERTFILE)."
    ),
    ssl_keyfile: Path | None = typer.Option(
        None, "--ssl-keyfile", help="The certificate's PEM private key (AD_SSL_KEYFILE)."
    ),
) -> None:
    """Start the server (the default command). Every setting, limits included, is an
    ``AD_`` environment variable: see docs/server.md."""
    if ctx.invoked_subcommand is not None:
        return
    from adservice.app import create_app
    from adservice.server import BoundedServer, uvicorn_config

    settings = _settings(
        database_url=database_url,
        host=host,
        port=port,
        log_level=log_level,
        ssl_certfile=ssl_certfile,
        ssl_keyfile=ssl_keyfile,
    )
    problem = device_problem(settings.proposer_device)
    if problem is not None:
        typer.echo(
            f"adserver: AD_PROPOSER_DEVICE={settings.proposer_device} cannot be used: {problem}; "
            "set AD_PROPOSER_DEVICE=cpu to fit proposals on the CPU",
            err=True,
        )
        raise typer.Exit(2)
    host = settings.host
    loopback = is_loopback(host)
    if settings.auth is None:
        settings.auth = not loopback
    if not settings.auth and not loopback and not insecure:
        typer.echo(
            f"adserver: refusing to serve {host} without authentication: set AD_AUTH=true and "
            "create tokens with `adserver token create`, or pass --insecure",
            err=True,
        )
        raise typer.Exit(2)
    logging.basicConfig(
        level=settings.log_level.upper(), format="%(asctime)s %(levelname)s %(name)s %(message)s"
    )
    server = BoundedServer(
        uvicorn_config(create_app(settings), settings), settings.shutdown_seconds
    )
    server.run()
    if not server.started:  # as uvicorn.run: the port was taken, or the app failed to start
        raise typer.Exit(3)


@tokens.command("create")
def create_token(
    role: str = typer.Option(..., "--role", help="reader, worker, user or admin."),
    name: str = typer.Option("", "--name", help="A label to recognise the token by."),
    database_url: str | None = DATABASE_OPTION,
) -> None:
    """Create a token and print it (only its hash is stored: it is shown this once)."""
    from adservice.auth import Role, new_token, token_digest
    from adservice.db import Database, upgrade_to_head
    from adservice.repository import tokens as token_repo

    if role not in Role.__members__:
        typer.echo(
            f"adserver: unknown role {role!r}; choose reader, worker, user or admin", err=True
        )
        raise typer.Exit(2)
    settings = _settings(database_url=database_url)
    upgrade_to_head(settings.database_url)
    db = Database(settings.database_url)
    token = new_token()
    with db.write() as session:
        token_repo.create_token(session, name=name or role, role=role, digest=token_digest(token))
    db.dispose()
    typer.echo(token)


@tokens.command("list")
def list_tokens(database_url: str | None = DATABASE_OPTION) -> None:
    """List tokens (id, role, name, created, revoked)."""
    from adservice.db import Database, upgrade_to_head
    from adservice.repository import tokens as token_repo

    settings = _settings(database_url=database_url)
    upgrade_to_head(settings.database_url)
    db = Database(settings.database_url)
    with db.read() as session:
        for row in token_repo.list_tokens(session):
            revoked = row.revoked_at.isoformat() if row.revoked_at else "-"
            typer.echo(f"{row.id}\t{row.role}\t{row.name}\t{row.created_at.isoformat()}\t{revoked}")
    db.dispose()


@tokens.command("revoke")
def revoke_token(token_id: int, database_url: str | None = DATABASE_OPTION) -> None:
    """Revoke a token by id; servers stop accepting it within seconds."""
    from adservice.db import Database
    from adservice.errors import NotFoundError
    from adservice.repository import tokens as token_repo

    db = Database(_settings(database_url=database_url).database_url)
    try:
        with db.write() as session:
            token_repo.revoke_token(session, token_id=token_id)
    except NotFoundError as error:
        typer.echo(f"adserver: {error.detail}", err=True)
        raise typer.Exit(1) from None
    finally:
        db.dispose()
    typer.echo(f"revoked token {token_id}")


@app.command("migrate")
def migrate(database_url: str | None = DATABASE_OPTION) -> None:
    """Bring the database schema to the newest revision, then exit. The server does this at
    start too; run it first where a deployment should not start servers on an old schema
    (Kubernetes: an init container). On PostgreSQL processes that migrate at once take
    turns (an advisory lock), so every replica may run it."""
    from adservice.db import upgrade_to_head

    settings = _settings(database_url=database_url)
    upgrade_to_head(settings.database_url)
    typer.echo("adserver: the database schema is up to date")


@app.command("tasks")
def list_tasks() -> None:
    """List the tasks and learners that studies may name (the installed plugins)."""
    from adclient.plugins import catalogue

    for line in catalogue().describe():
        typer.echo(line)


def main() -> None:
    app()
