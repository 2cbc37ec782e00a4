"""The FastAPI app factory: ``create_app(settings)``; OpenAPI at /docs, health at /health."""

from __future__ import annotations

import asyncio
import inspect
import logging
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager, suppress
from importlib.metadata import PackageNotFoundError
from importlib.metadata import version as _pkg_version
from typing import Any, Literal

from fastapi import FastAPI
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import JSONResponse
from pydantic import BaseModel
from sqlalchemy import text

from app.api import errors
from app.api.limits import BodySizeLimit, SecurityHeaders
from app.api.routes import auth, drift, experiments, sim_prior, trials, workers
from app.config import Settings
from app.db.session import Database
from app.service.auth import LoginLimiter
from app.service.compute import ComputeRunner
from app.service.leases import grant_restart_grace, sweep_expired
from app.service.runs import PreviewRunner

log = logging.getLogger("handful.api")

try:
    VERSION = _pkg_version("handful")
except PackageNotFoundError:  # running from a source tree
    VERSION = "0.0.0"


async def _call(hook: Callable[..., Any], app: FastAPI) -> None:
    params = inspect.signature(hook).parameters
    result = hook(app) if params else hook()
    if inspect.isawaitable(result):
        await result


async def _sweep_forever(app: FastAPI) -> None:
    """Expire lost leases every ``lease_sweep_interval_s`` even when no worker calls in."""
    settings: Settings = app.state.settings
    db: Database = app.state.db

    def sweep() -> int:
        with db.write() as s:
            return sweep_expired(
                s,
                max_attempts=settings.max_attempts,
                orphan_after_s=max(60.0, settings.lease_seconds),
            )

    while True:
        await asyncio.sleep(settings.lease_sweep_interval_s)
        try:
            n = await run_in_threadpool(sweep)
            if n:
                log.info("expired %d lease(s)", n)
        except Exception:  # keep sweeping; the next round retries
            log.exception("lease sweep failed")


@asynccontextmanager
async def _lifespan(app: FastAPI) -> AsyncIterator[None]:
    settings: Settings = app.state.settings
    db: Database = app.state.db

    def grace() -> int:
        with db.write() as s:
            return grant_restart_grace(s, lease_seconds=settings.lease_seconds)

    n = await run_in_threadpool(grace)
    if n:
        log.info(
            "gave %d active lease(s) a fresh %.0f s after the restart", n, settings.lease_seconds
        )
    for hook in list(app.state.startup_hooks):
        await _call(hook, app)
    sweeper = asyncio.create_task(_sweep_forever(app))
    try:
        yield
    finally:
        sweeper.cancel()
        with suppress(asyncio.CancelledError):
            await sweeper
        for hook in list(app.state.shutdown_hooks):
            try:
                await _call(hook, app)
            except Exception:
                log.exception("shutdown hook %r failed", hook)
        app.state.previews.shutdown()
        app.state.compute.shutdown()
        app.state.db.dispose()


def _warm_imports(settings: Settings) -> None:
    """Import the optimisers (torch, BoTorch) and the simulator (MuJoCo) now, at start-up,
    so the first request that needs them does not wait many seconds for the imports; set
    torch's threads for the GP work (``settings.torch_threads``)."""
    import app.optim.bo
    from app.procs import set_torch_threads

    set_torch_threads(settings.torch_threads)

    try:
        import app.sim  # noqa: F401
    except ImportError as exc:  # a hardware-only server may run without MuJoCo
        log.warning("simulator unavailable: %s", exc)


def _offline_docs(app: FastAPI) -> None:
    """``/docs``: Swagger UI from the installed ``swagger-ui-bundle`` package (its JS and CSS
    at ``/docs-assets``), so a lab without internet access still gets the API's docs."""
    from fastapi.openapi.docs import get_swagger_ui_html
    from fastapi.staticfiles import StaticFiles
    from swagger_ui_bundle import swagger_ui_path

    app.mount("/docs-assets", StaticFiles(directory=swagger_ui_path), name="docs-assets")

    @app.get("/docs", include_in_schema=False)
    def docs() -> Any:
        return get_swagger_ui_html(
            openapi_url=app.openapi_url or "/openapi.json",
            title="handful API",
            swagger_js_url="/docs-assets/swagger-ui-bundle.js",
            swagger_css_url="/docs-assets/swagger-ui.css",
            swagger_favicon_url="/docs-assets/favicon-32x32.png",
        )


def _twins(app: FastAPI) -> None:
    """Every hardware trial's sim twins, made on a background thread of the server
    (``app.service.twins``, like previews); started and stopped with the app."""
    from app.service.twins import TwinRunner

    runner = TwinRunner(app.state.db, None, interval_s=app.state.settings.twin_interval_s)
    app.state.twins = runner
    app.state.startup_hooks.append(runner.start)
    app.state.shutdown_hooks.append(runner.stop)


class HealthRead(BaseModel):
    status: Literal["ok", "error"]
    db: str
    version: str


def create_app(settings: Settings | None = None) -> FastAPI:
    """Build the app over an already-migrated database (``handful serve`` migrates first).

    ``app.state`` holds ``settings``, ``db`` (Database), ``previews`` (PreviewRunner) and
    ``startup_hooks`` / ``shutdown_hooks``: callables (sync or async, taking the app or
    nothing) run by the lifespan; app.dashboard registers its own there.
    """
    settings = settings or Settings()
    settings.artifacts_dir.mkdir(parents=True, exist_ok=True)
    _warm_imports(settings)
    app = FastAPI(
        title="handful",
        version=VERSION,
        summary="Trial service: BayesOpt with a person in the loop for a pneumatic soft arm.",
        lifespan=_lifespan,
        docs_url=None,  # served below from the installed swagger-ui-bundle: no CDN, works offline
        redoc_url=None,
    )
    _offline_docs(app)
    app.state.settings = settings
    app.state.db = Database(
        settings.db_url,
        sqlite_synchronous=settings.sqlite_synchronous,
        busy_timeout_s=settings.db_busy_timeout_s,
    )
    app.state.previews = PreviewRunner(settings.preview.workers, settings.preview.max_jobs)
    app.state.compute = ComputeRunner(settings.compute_workers, settings.suggest_timeout_s)
    app.state.login_limiter = LoginLimiter(settings.login_max_failures, settings.login_window_s)
    app.state.startup_hooks = []
    app.state.shutdown_hooks = []
    _twins(app)
    app.add_middleware(BodySizeLimit, max_bytes=settings.max_body_bytes)
    app.add_middleware(SecurityHeaders)
    errors.install(app)
    for module in (auth, experiments, drift, trials, workers, sim_prior):
        app.include_router(module.router, prefix="/api", responses=errors.ERROR_RESPONSES)

    @app.get(
        "/health",
        tags=["health"],
        response_model=HealthRead,
        responses={503: {"model": HealthRead, "description": "The database does not answer"}},
    )
    def health() -> JSONResponse:
        """Liveness and database check: ``{status, db, version}``."""
        try:
            with app.state.db.read() as s:
                s.execute(text("SELECT 1"))
            return JSONResponse({"status": "ok", "db": "ok", "version": VERSION})
        except Exception as exc:
            return JSONResponse(
                {"status": "error", "db": f"error: {exc}", "version": VERSION}, status_code=503
            )

    if settings.dashboard_enabled:
        try:
            from app.dashboard import mount_dashboard
        except ImportError as exc:
            log.warning("dashboard not mounted: %s", exc)
        else:
            mount_dashboard(app, settings)
    return app
