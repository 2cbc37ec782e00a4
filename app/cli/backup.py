"""`handful backup PATH` / `handful restore PATH`: the database and artifacts, consistent while
the server runs (SQLite's online backup API); `handful export ID PATH` / `handful import PATH`:
one experiment as a JSON bundle."""

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


def _settings(data_dir: Path | None):  # type: ignore[no-untyped-def]
    from app.config import Settings

    return Settings(data_dir=data_dir) if data_dir is not None else Settings()


def export_cmd(
    experiment_id: int = typer.Argument(..., help="the experiment's id"),
    path: Path = typer.Argument(..., help="the bundle to write (.json)"),
    data_dir: Path | None = DataDir,
) -> None:
    """Write experiment ID with everything about it (trials, raw measurements, confirmations,
    trajectories, audit log) as one JSON bundle."""
    import json

    from app.db.session import Database
    from app.service.bundle import export_bundle
    from app.service.errors import ServiceError

    settings = _settings(data_dir)
    db = Database(settings.db_url)
    try:
        with db.read() as s:
            bundle = export_bundle(s, experiment_id, settings.artifacts_dir)
    except ServiceError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(1) from None
    finally:
        db.dispose()
    path.write_text(json.dumps(bundle, allow_nan=False))
    typer.echo(
        f"experiment {experiment_id}: {len(bundle['trials'])} trial(s), "
        f"{len(bundle['audit'])} audit row(s) written to {path}"
    )


def import_cmd(
    path: Path = typer.Argument(..., help="a bundle written by `handful export`"),
    data_dir: Path | None = DataDir,
) -> None:
    """Store a bundle as a new experiment (new ids; everything else as exported)."""
    import json

    from app.db.migrate import upgrade
    from app.db.session import Database
    from app.service.auth import SYSTEM
    from app.service.bundle import import_bundle
    from app.service.errors import ServiceError

    settings = _settings(data_dir)
    upgrade(settings.db_url)
    db = Database(settings.db_url)
    try:
        bundle = json.loads(path.read_text())
        with db.write() as s:
            exp_id = import_bundle(s, bundle, settings.artifacts_dir, actor=SYSTEM)
    except (ServiceError, ValueError) as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(1) from None
    finally:
        db.dispose()
    typer.echo(f"imported {path} as experiment {exp_id}")


def register(app: typer.Typer) -> None:
    app.command("backup")(backup_cmd)
    app.command("restore")(restore_cmd)
    app.command("export")(export_cmd)
    app.command("import")(import_cmd)
