"""``adserver``: run the activedesign HTTP service."""

from __future__ import annotations

import logging

import typer
import uvicorn

from adservice.settings import Settings

app = typer.Typer(add_completion=False, help="The activedesign server.")


@app.callback(invoke_without_command=True)
def serve(
    ctx: typer.Context,
    host: str = typer.Option("127.0.0.1", envvar="AD_HOST", help="Address to bind."),
    port: int = typer.Option(8000, envvar="AD_PORT", help="Port to bind."),
    database_url: str | None = typer.Option(
        None,
        "--database-url",
        help="SQLAlchemy URL (default: AD_DATABASE_URL or ./activedesign.db).",
    ),
    log_level: str = typer.Option("info", envvar="AD_LOG_LEVEL"),
) -> None:
    """Start the server (the default command)."""
    if ctx.invoked_subcommand is not None:
        return
    from adservice.app import create_app

    overrides = {"database_url": database_url} if database_url else {}
    settings = Settings(**overrides)
    logging.basicConfig(
        level=log_level.upper(), format="%(asctime)s %(levelname)s %(name)s %(message)s"
    )
    uvicorn.run(create_app(settings), host=host, port=port, log_level=log_level, access_log=False)


def main() -> None:
    app()
