"""`handful serve`: run the migrations, then the API (and dashboard) under uvicorn."""

from __future__ import annotations

from pathlib import Path

import typer


def serve(
    host: str | None = typer.Option(None, help="interface (default HANDFUL_HOST or 127.0.0.1)"),
    port: int | None = typer.Option(None, help="TCP port (default HANDFUL_PORT or 8000)"),
    data_dir: Path | None = typer.Option(None, help="data folder (default HANDFUL_DATA_DIR)"),
    log_level: str = typer.Option("info", help="uvicorn log level"),
) -> None:
    """Migrate the database to the latest schema and serve the API (embedded SQLite by default)."""
    import uvicorn

    from app.api.main import create_app
    from app.config import Settings
    from app.db.migrate import upgrade

    overrides: dict[str, object] = {}
    if host is not None:
        overrides["host"] = host
    if port is not None:
        overrides["port"] = port
    if data_dir is not None:
        overrides["data_dir"] = data_dir
    settings = Settings(**overrides)  # type: ignore[arg-type]
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    upgrade(settings.db_url)
    typer.echo(f"handful: database {settings.db_url} at the latest schema")
    app = create_app(settings)
    uvicorn.run(app, host=settings.host, port=settings.port, log_level=log_level)


def register(app: typer.Typer) -> None:
    """Add `serve` to the root app."""
    app.command("serve")(serve)
