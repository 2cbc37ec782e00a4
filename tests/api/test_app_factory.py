"""create_app: lifespan hooks (for app.dashboard), settings from the environment."""

from __future__ import annotations

from fastapi.testclient import TestClient

from app.api.main import create_app
from app.config import Settings


def test_startup_and_shutdown_hooks_run(migrated_db, tmp_path):
    settings = Settings(
        data_dir=tmp_path / "data", database_url=migrated_db, dashboard_enabled=False
    )
    app = create_app(settings)
    calls: list[str] = []

    async def async_start(app_) -> None:
        calls.append(f"start:{app_.title}")

    app.state.startup_hooks.append(async_start)
    app.state.shutdown_hooks.append(lambda: calls.append("stop"))
    with TestClient(app) as client:
        assert calls == ["start:handful"]
        assert client.get("/health").json()["db"] == "ok"
    assert calls == ["start:handful", "stop"]


def test_settings_from_environment(monkeypatch, tmp_path):
    monkeypatch.setenv("HANDFUL_DATA_DIR", str(tmp_path / "d"))
    monkeypatch.setenv("HANDFUL_LEASE_SECONDS", "12.5")
    monkeypatch.setenv("HANDFUL_PREVIEW__WORKERS", "3")
    monkeypatch.setenv("HANDFUL_SQLITE_SYNCHRONOUS", "NORMAL")
    s = Settings()
    assert s.lease_seconds == 12.5 and s.preview.workers == 3
    assert s.sqlite_synchronous == "NORMAL"
    assert s.db_url == f"sqlite:///{(tmp_path / 'd' / 'handful.db').resolve()}"
    monkeypatch.setenv("HANDFUL_DATABASE_URL", "postgresql+psycopg://u:p@db/handful")
    assert Settings().db_url == "postgresql+psycopg://u:p@db/handful"
