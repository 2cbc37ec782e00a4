"""`handful user add|list|disable|enable|set-password` and `handful token create|list|revoke`.

They write the server's database directly; the server looks every token up on every request,
so a revoked token or a disabled user is refused from the next request on."""

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


def _in_write(data_dir: Path | None, work):  # type: ignore[no-untyped-def]
    """``work(session)`` in a write transaction; a ServiceError is one line, exit 1."""
    from app.service.errors import ServiceError

    db = _database(data_dir)
    try:
        with db.write() as s:
            return work(s)
    except ServiceError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(1) from None
    finally:
        db.dispose()


def _when(t) -> str:  # type: ignore[no-untyped-def]
    return "-" if t is None else t.strftime("%Y-%m-%d %H:%M:%SZ")


@user_app.command("list")
def user_list(data_dir: Path | None = DataDir) -> None:
    """Every user: name, role, whether they can log in, disabled or not."""
    from app.service.auth import list_users

    def work(s):  # type: ignore[no-untyped-def]
        return [
            (u.username, u.role, u.password_hash is not None, u.disabled) for u in list_users(s)
        ]

    for name, role, password, disabled in _in_write(data_dir, work):
        state = "disabled" if disabled else "active"
        typer.echo(f"{name}\t{role}\t{state}\t{'password' if password else 'token only'}")


@user_app.command("disable")
def user_disable(name: str, data_dir: Path | None = DataDir) -> None:
    """Disable user NAME: no login, and every token of theirs refused from the next request."""
    from app.service.auth import set_disabled

    _in_write(data_dir, lambda s: set_disabled(s, name, True))
    typer.echo(f"user {name} disabled")


@user_app.command("enable")
def user_enable(name: str, data_dir: Path | None = DataDir) -> None:
    """Enable a disabled user again (their unrevoked, unexpired tokens work again)."""
    from app.service.auth import set_disabled

    _in_write(data_dir, lambda s: set_disabled(s, name, False))
    typer.echo(f"user {name} enabled")


@user_app.command("set-password")
def user_set_password(name: str, data_dir: Path | None = DataDir) -> None:
    """Set NAME's password (prompted); their login tokens are revoked."""
    from app.service.auth import set_password

    secret = typer.prompt("password", hide_input=True, confirmation_prompt=True)
    n = _in_write(data_dir, lambda s: set_password(s, name, secret))
    typer.echo(f"password of {name} set; {n} login token(s) revoked")


@token_app.command("list")
def token_list(
    user: str | None = typer.Option(None, "--user", help="only this user's tokens"),
    data_dir: Path | None = DataDir,
) -> None:
    """Tokens (id, user, label, created, expires, revoked); the secrets are never stored."""
    from app.service.auth import list_tokens

    for t in _in_write(data_dir, lambda s: list_tokens(s, user)):
        state = "revoked " + _when(t.revoked_at) if t.revoked_at else "active"
        typer.echo(
            f"{t.id}\t{t.username}\t{t.label}\tcreated {_when(t.created_at)}\t"
            f"expires {_when(t.expires_at)}\t{state}"
        )


@token_app.command("revoke")
def token_revoke(
    token_id: int | None = typer.Argument(None, help="the token's id (handful token list)"),
    user: str | None = typer.Option(None, "--user", help="revoke every token of this user"),
    data_dir: Path | None = DataDir,
) -> None:
    """Revoke one token by id, or every token of --user; refused from the next request on."""
    from app.service.auth import revoke_token, revoke_tokens

    if (token_id is None) == (user is None):
        typer.echo("error: give a token id or --user NAME (one of them)", err=True)
        raise typer.Exit(2)
    if user is not None:
        n = _in_write(data_dir, lambda s: revoke_tokens(s, user))
        typer.echo(f"{n} token(s) of {user} revoked")
    else:
        assert token_id is not None
        done = _in_write(data_dir, lambda s: revoke_token(s, token_id))
        typer.echo(f"token {token_id} revoked" if done else f"token {token_id} was revoked already")


@token_app.command("create")
def token_create(
    name: str,
    label: str = typer.Option("cli", help="a note stored with the token"),
    expires_days: float | None = typer.Option(
        None, "--expires-days", min=0.001, help="valid this many days (default: until revoked)"
    ),
    data_dir: Path | None = DataDir,
) -> None:
    """Issue a new API token for user NAME and print it (it is shown only once)."""
    from app.service.auth import create_token
    from app.service.errors import ServiceError

    ttl = None if expires_days is None else expires_days * 86400.0
    db = _database(data_dir)
    try:
        with db.write() as s:
            token = create_token(s, name, label=label, ttl_s=ttl)
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
