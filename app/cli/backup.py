"""`handful backup PATH` and `handful restore PATH`: the database and artifacts, consistent
while the server runs (SQLite's online backup API)."""

from __future__ import annotations

from pathlib import Path

import typer

DataDir = typer.Option(None, "--data-dir", help="data folder (default HANDFUL_DATA_DIR)")


def _data_dir(data_dir: Path | None) -> Path:
    from app.config import Settings

    settings = Settings(data_dir=data_dir) if data_dir is not None else Settings()
    if not settings.db_url.startswith("sqlite"):
        typer.echo("error: backup/restore handle SQLite; use pg_dump for PostgreSQL", err=True)
        raise typer.Exit(2)
    return settings.data_dir


def backup_cmd(
    path: Path = typer.Argument(..., help="a new (or empty) folder for the backup"),
    data_dir: Path | None = DataDir,
) -> None:
    """Back up the database and the artifacts it refers to into PATH (safe while serving)."""
    from app.service.backup import backup
    from app.service.errors import ServiceError

    try:
        m = backup(_data_dir(data_dir), path)
    except ServiceError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(1) from None
    rows = ", ".join(f"{n} {t}" for t, n in m["database"]["rows"].items())
    typer.echo(f"backed up to {path}: {rows}; {len(m['artifacts'])} artifact file(s)")
    if m["missing_artifacts"]:
        n = len(m["missing_artifacts"])
        typer.echo(f"warning: {n} artifact file(s) were missing", err=True)


def restore_cmd(
    path: Path = typer.Argument(..., help="a folder made by `handful backup`"),
    force: bool = typer.Option(False, "--force", help="replace an existing database"),
    data_dir: Path | None = DataDir,
) -> None:
    """Restore a backup into the data folder (stop the server first); checks it first."""
    from app.db.migrate import upgrade
    from app.service.backup import restore
    from app.service.errors import ServiceError

    target = _data_dir(data_dir)
    try:
        m = restore(path, target, force=force)
    except ServiceError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(1) from None
    upgrade(f"sqlite:///{(target / 'handful.db').resolve()}")  # a backup from an older version
    typer.echo(f"restored {path} (made {m['made_at']}) into {target}")


def register(app: typer.Typer) -> None:
    app.command("backup")(backup_cmd)
    app.command("restore")(restore_cmd)
