"""``adserver``: run the activedesign HTTP service, and manage its API tokens."""

from __future__ import annotations

import ipaddress
import logging
import socket

import typer
import uvicorn

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


def _settings(database_url: str | None) -> Settings:
    return Settings(database_url=database_url) if database_url else Settings()


@app.callback(invoke_without_command=True)
def serve(
    ctx: typer.Context,
    host: str = typer.Option("127.0.0.1", envvar="AD_HOST", help="Address to bind."),
    port: int = typer.Option(8000, envvar="AD_PORT", help="Port to bind."),
    database_url: str | None = DATABASE_OPTION,
    insecure: bool = typer.Option(
        False, "--insecure", help="Allow a non-loopback address without authentication."
    ),
    log_level: str = typer.Option("info", envvar="AD_LOG_LEVEL"),
) -> None:
    """Start the server (the default command)."""
    if ctx.invoked_subcommand is not None:
        return
    from adservice.app import create_app

    settings = _settings(database_url)
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
        level=log_level.upper(), format="%(asctime)s %(levelname)s %(name)s %(message)s"
    )
    uvicorn.run(create_app(settings), host=host, port=port, log_level=log_level, access_log=False)


@tokens.command("create")
def create_token(
    role: str = typer.Option(..., "--role", help="reader, worker, user or admin."),
    name: str = typer.Option("", "--name", help="A label to recognise the token by."),
    database_url: str | None = DATABASE_OPTION,
) -> None:
    """Create a token and print it (only its hash is stored: it is shown this once)."""
    from adservice import repository
    from adservice.auth import Role, new_token, token_digest
    from adservice.db import Database, upgrade_to_head

    if role not in Role.__members__:
        typer.echo(
            f"adserver: unknown role {role!r}; choose reader, worker, user or admin", err=True
        )
        raise typer.Exit(2)
    settings = _settings(database_url)
    upgrade_to_head(settings.database_url)
    db = Database(settings.database_url)
    token = new_token()
    with db.write() as session:
        repository.create_token(session, name=name or role, role=role, digest=token_digest(token))
    db.dispose()
    typer.echo(token)


@tokens.command("list")
def list_tokens(database_url: str | None = DATABASE_OPTION) -> None:
    """List tokens (id, role, name, created, revoked)."""
    from adservice import repository
    from adservice.db import Database, upgrade_to_head

    settings = _settings(database_url)
    upgrade_to_head(settings.database_url)
    db = Database(settings.database_url)
    with db.read() as session:
        for row in repository.list_tokens(session):
            revoked = row.revoked_at.isoformat() if row.revoked_at else "-"
            typer.echo(f"{row.id}\t{row.role}\t{row.name}\t{row.created_at.isoformat()}\t{revoked}")
    db.dispose()


@tokens.command("revoke")
def revoke_token(token_id: int, database_url: str | None = DATABASE_OPTION) -> None:
    """Revoke a token by id; servers stop accepting it within seconds."""
    from adservice import repository
    from adservice.db import Database
    from adservice.errors import NotFoundError

    db = Database(_settings(database_url).database_url)
    try:
        with db.write() as session:
            repository.revoke_token(session, token_id=token_id)
    except NotFoundError as error:
        typer.echo(f"adserver: {error.detail}", err=True)
        raise typer.Exit(1) from None
    finally:
        db.dispose()
    typer.echo(f"revoked token {token_id}")


def main() -> None:
    app()
