"""`handful user add NAME --role R [--password]` and `handful token create NAME`."""

from __future__ import annotations

from pathlib import Path

import typer

user_app = typer.Typer(help="Users (operator, viewer, worker).", no_args_is_help=True)
token_app = typer.Typer(help="API tokens.", no_args_is_help=True)

DataDir = typer.Option(None, "--data-dir", help="data folder (default HANDFUL_DATA_DIR)")


def _database(data_dir: Path | None):
    from app.config import Settings
    from app.db.migrate import upgrade
    from app.db.session import Database

    settings = Settings(data_dir=data_dir) if data_dir is not None else Settings()
    upgrade(settings.db_url)
    return Database(settings.db_url)


@user_app.command("add")
def user_add(
    name: str,
    role: str = typer.Option(..., "--role", help="operator | viewer | worker"),
    password: bool = typer.Option(False, "--password", help="prompt for a login password"),
    data_dir: Path | None = DataDir,
) -> None:
    """Create a user (and, with --password, let them log in to the dashboard)."""
    from app.service.auth import add_user
    from app.service.errors import ServiceError

    secret = None
    if password:
        secret = typer.prompt("password", hide_input=True, confirmation_prompt=True)
    db = _database(data_dir)
    try:
        with db.write() as s:
            add_user(s, name, role, password=secret)
    except ServiceError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(1) from None
    finally:
        db.dispose()
    typer.echo(f"user {name} ({role}) added")


@token_app.command("create")
def token_create(
    name: str,
    label: str = typer.Option("cli", help="a note stored with the token"),
    data_dir: Path | None = DataDir,
) -> None:
    """Issue a new API token for user NAME and print it (it is shown only once)."""
    from app.service.auth import create_token
    from app.service.errors import ServiceError

    db = _database(data_dir)
    try:
        with db.write() as s:
            token = create_token(s, name, label=label)
    except ServiceError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(1) from None
    finally:
        db.dispose()
    typer.echo(token)


def register(app: typer.Typer) -> None:
    """Add the `user` and `token` groups to the root app."""
    app.add_typer(user_app, name="user")
    app.add_typer(token_app, name="token")
