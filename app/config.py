"""Server settings: one pydantic-settings ``Settings`` read from ``HANDFUL_*`` environment vars.

Examples: ``HANDFUL_DATA_DIR=/srv/handful``, ``HANDFUL_DATABASE_URL=postgresql+psycopg://...``,
``HANDFUL_LEASE_SECONDS=30``, ``HANDFUL_PREVIEW__WORKERS=2`` (nested groups use ``__``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import BaseModel, Field
from pydantic_settings import BaseSettings, SettingsConfigDict

from app.policy import SIM_MAX_PRESSURE_PA, HardwareCeilings


class PreviewSettings(BaseModel):
    """Sim previews of a trial's schedule, run off the request path."""

    workers: int = Field(1, ge=1, le=64, description="threads running preview rollouts")
    max_jobs: int = Field(64, ge=1, description="finished preview jobs kept in memory")


class RobotSettings(BaseModel):
    """The robot's absolute hardware ceilings, Pa (``HANDFUL_ROBOT__SOURCE_PA=205000``, ...).

    Every hardware experiment's limits must lie within them (they can only narrow them), and
    every hardware schedule is checked against them on suggest, attach, preview, confirm and
    claim, whatever the experiment says. Defaults: the paper's robot (shared/ROBOT.md).
    """

    source_pa: float = Field(205_000.0, gt=0, le=10e6, description="supply pressure, Pa")
    max_step_pa: float = Field(30_000.0, gt=0, le=10e6, description="largest offset, Pa")
    chamber_max_pa: float = Field(
        SIM_MAX_PRESSURE_PA, gt=0, le=10e6, description="chambers' rating, Pa (40 psi)"
    )

    def ceilings(self) -> HardwareCeilings:
        """As the policy's ``HardwareCeilings`` (what the checks take)."""
        return HardwareCeilings(
            source_pa=self.source_pa,
            max_step_pa=self.max_step_pa,
            chamber_max_pa=self.chamber_max_pa,
        )


class Settings(BaseSettings):
    """Everything the server reads from its environment (prefix ``HANDFUL_``)."""

    model_config = SettingsConfigDict(
        env_prefix="HANDFUL_", env_nested_delimiter="__", extra="ignore"
    )

    data_dir: Path = Field(Path("data"), description="database (SQLite) and artifacts folder")
    database_url: str | None = Field(
        None, description="SQLAlchemy URL; default sqlite:///<data_dir>/handful.db"
    )
    sqlite_synchronous: Literal["FULL", "NORMAL"] = Field(
        "FULL", description="FULL: commits survive power loss; NORMAL: only a killed process"
    )
    host: str = "127.0.0.1"
    port: int = Field(8000, ge=1, le=65535)
    viser_port: int = Field(8080, ge=1, le=65535)
    dashboard_enabled: bool = True
    public_read: bool = Field(False, description="allow GETs under /api without a token")
    lease_seconds: float = Field(60.0, gt=0, description="a worker's lease lasts this long")
    lease_sweep_interval_s: float = Field(5.0, gt=0, description="expired-lease sweep period")
    max_attempts: int = Field(3, ge=1, description="claims of one sim trial before `failed`")
    max_body_bytes: int = Field(16 * 1024 * 1024, ge=1024, description="largest request body")
    preview: PreviewSettings = Field(default_factory=PreviewSettings)
    robot: RobotSettings = Field(default_factory=RobotSettings)
    torch_threads: int = Field(
        1,
        ge=1,
        le=1024,
        description="torch's intra-op threads for GP fits and acquisition searches (these GPs "
        "are small: one thread is as fast as two on an idle machine, several times faster on "
        "a busy one; parallelism comes from running optimisers side by side)",
    )
    db_busy_timeout_s: float = Field(
        5.0,
        gt=0,
        le=300,
        description="a write waits this long for the database, then 503 database_busy",
    )
    token_ttl_s: float = Field(
        12 * 3600.0, gt=0, description="a login token's lifetime, s (rotate to extend)"
    )
    login_max_failures: int = Field(
        5, ge=1, description="failed logins per user (4x per address) in the window"
    )
    login_window_s: float = Field(900.0, gt=0, description="the failed-login window, s")
    suggest_timeout_s: float = Field(
        120.0, gt=0, le=3600, description="a suggestion's (or GP view's) time budget; then 503"
    )
    compute_workers: int = Field(2, ge=1, le=64, description="processes running optimisers")
    twin_interval_s: float = Field(
        1.0,
        gt=0,
        le=3600,
        description="how often the server looks for hardware trials "
        "still without their sim twin (made in the compute processes), s",
    )

    @property
    def db_url(self) -> str:
        """The database URL actually used (embedded SQLite under data_dir by default)."""
        if self.database_url:
            return self.database_url
        return f"sqlite:///{(self.data_dir / 'handful.db').resolve()}"

    @property
    def artifacts_dir(self) -> Path:
        """Where trajectories and other trial files live (paths in the DB are relative to it)."""
        return self.data_dir / "artifacts"
