"""The operator's dashboard: HTML pages, their static JS/CSS, plotly.js, and the viser 3D server.

Pages are plain HTML (``web/templates``) whose small ES modules (``web/static/js``) call the
JSON API under ``/api`` with the token kept in the browser; nothing here reads the database.
The one JSON route of its own, ``POST /viz/views``, turns a trial or a preview job into a 3D
replay on the viser server; it fetches what it draws through the same API (in process, with
the caller's token), so it sees exactly what the caller may see.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import threading
from collections import OrderedDict
from pathlib import Path
from typing import Any, TypeVar

import httpx
import numpy as np
from fastapi import APIRouter, FastAPI, HTTPException, Request, WebSocket, WebSocketDisconnect
from fastapi.responses import (
    FileResponse,
    HTMLResponse,
    JSONResponse,
    RedirectResponse,
    Response,
)
from fastapi.staticfiles import StaticFiles
from fastapi.templating import Jinja2Templates
from pydantic import BaseModel, Field

from app.service.schemas import ExperimentRead, PreviewJobRead, TrialRead
from app.viz import Replay, VizServer

log = logging.getLogger(__name__)

WEB_DIR = Path(__file__).resolve().parents[1] / "web"
#: the proxied viser client (``/viz/client/``) is framed by our own pages, and only by them
VIZ_CLIENT_CSP = "frame-ancestors 'self'; object-src 'none'; base-uri 'self'"


def plotly_js_path() -> Path:
    """plotly.min.js as shipped inside the installed ``plotly`` Python package."""
    import plotly

    path = Path(plotly.__file__).resolve().parent / "package_data" / "plotly.min.js"
    if not path.is_file():
        raise FileNotFoundError(f"plotly.min.js not found at {path}; reinstall plotly")
    return path


class ViewRequest(BaseModel):
    """What a tab wants to see in 3D: a trial's replay or a preview job's rollout."""

    trial_id: int | None = Field(None, ge=1, description="replay this trial")
    preview_job_id: str | None = Field(
        None, max_length=200, description="replay this preview job's rollout (of trial_id)"
    )
    overlay_trial_id: int | None = Field(None, ge=1, description="overlay this trial, see-through")


class ApiRefused(Exception):
    """The API answered a fetch made on the caller's behalf with an error."""

    def __init__(self, status_code: int, detail: Any) -> None:
        super().__init__(str(detail))
        self.status_code = status_code
        self.detail = detail


M = TypeVar("M", bound=BaseModel)


async def _get(client: httpx.AsyncClient, path: str, auth: str | None, schema: type[M]) -> M:
    """GET ``path`` through the API and parse the reply with its published schema."""
    return schema.model_validate(await _get_json(client, path, auth))


async def _get_json(client: httpx.AsyncClient, path: str, auth: str | None) -> Any:
    headers = {"Authorization": auth} if auth else {}
    response = await client.get(path, headers=headers)
    if response.status_code >= 400:
        try:
            detail = response.json().get("detail", response.text)
        except ValueError:
            detail = response.text
        raise ApiRefused(response.status_code, detail)
    return response.json()


def _trajectory_qpos(trajectory: Any) -> tuple[np.ndarray, np.ndarray] | None:
    """(time_s (T,), qpos (T, nq)) from a trajectory JSON, or None when it has no qpos."""
    if not isinstance(trajectory, dict):
        return None
    qpos, time_s = trajectory.get("qpos"), trajectory.get("time_s")
    if qpos is None or time_s is None:
        return None
    q = np.asarray(qpos, dtype=np.float64)
    t = np.asarray(time_s, dtype=np.float64)
    if q.ndim != 2 or t.ndim != 1 or q.shape[0] != t.shape[0] or q.shape[0] == 0:
        return None
    return t, q


_ROLLOUTS: OrderedDict[str, tuple[np.ndarray, np.ndarray]] = OrderedDict()
_ROLLOUTS_KEPT = 16
_ROLLOUT_LOCK = threading.Lock()
# At most two 3D rollouts at once, whoever asks: a tab reload or a busy page cannot pile
# simulator runs onto the server.
_ROLLOUT_SLOTS = threading.BoundedSemaphore(2)


def _simulate_qpos(
    task: str, preset: str, schedule: Any, release_step: int | None, command_hold: str = "zero"
) -> tuple[np.ndarray, np.ndarray]:
    """A sim rollout of the schedule with qpos recorded: (time_s (T,), qpos (T, nq)).

    The simulator is deterministic, so results are kept (newest 16) by task, preset, command
    hold and the schedule's hash.
    """
    from app.policy import schedule_hash
    from app.sim import rollout

    sched = np.asarray(schedule, dtype=np.float64)
    key = f"{task}/{preset}/{command_hold}/{schedule_hash(sched, release_step)}"
    with _ROLLOUT_LOCK:
        if key in _ROLLOUTS:
            _ROLLOUTS.move_to_end(key)
            return _ROLLOUTS[key]
    with _ROLLOUT_SLOTS:
        result = rollout(
            task,
            sched,
            release_step=release_step,
            preset=preset,
            record_qpos=True,
            command_hold=command_hold,
        )
    out = (np.asarray(result.trajectory.time_s), np.asarray(result.trajectory.qpos))
    with _ROLLOUT_LOCK:
        _ROLLOUTS[key] = out
        while len(_ROLLOUTS) > _ROLLOUTS_KEPT:
            _ROLLOUTS.popitem(last=False)
    return out


async def _trial_replay(
    client: httpx.AsyncClient, auth: str | None, trial_id: int, role: str
) -> tuple[Replay, TrialRead]:
    """A trial's recorded qpos if it has some, else a sim rollout of what it ran (or plans)."""
    trial = await _get(client, f"/api/trials/{trial_id}", auth, TrialRead)
    experiment = await _get(client, f"/api/experiments/{trial.experiment_id}", auth, ExperimentRead)
    task, preset = experiment.task, experiment.sim_preset
    recorded = None
    if trial.has_trajectory:
        try:
            recorded = _trajectory_qpos(
                await _get_json(client, f"/api/trials/{trial_id}/trajectory?format=json", auth)
            )
        except ApiRefused as exc:
            log.info("trial %s: no trajectory for 3D (%s)", trial_id, exc)
    if recorded is not None:
        time_s, qpos = recorded
        how = "recorded"
    else:
        executed = trial.executed_pressure_schedule_pa
        if executed is not None:
            schedule, release = executed, trial.executed_release_step
            how = "simulated from its executed schedule"
        else:
            schedule, release = trial.pressure_schedule_pa, trial.release_step
            how = "simulated from its plan"
        time_s, qpos = await asyncio.to_thread(
            _simulate_qpos, task, preset, schedule, release, experiment.command_hold
        )
    label = f"trial {trial.index} ({role}, {how})"
    return Replay(task, time_s, qpos, label, preset), trial


def api_schema_module(openapi: dict[str, Any]) -> str:
    """``/api-schema.js``: the OpenAPI document's schemas, the status sets and robot facts."""
    from app.policy import RELEASE_TASKS, SIM_MAX_PRESSURE_PA, TASKS
    from app.service.lifecycle import STATUSES

    preview = PreviewJobRead.model_json_schema()["properties"]["status"]["enum"]
    consts = {
        "SCHEMAS": openapi["components"]["schemas"],
        "TRIAL_STATUSES": list(STATUSES),
        "PREVIEW_STATUSES": preview,
        "TASKS": list(TASKS),
        "RELEASE_TASKS": sorted(RELEASE_TASKS),
        "SIM_MAX_PRESSURE_PA": SIM_MAX_PRESSURE_PA,
    }
    lines = [
        "// Generated by app.dashboard.api_schema_module from the running server: do not edit."
    ]
    lines += [f"export const {k} = {json.dumps(v, sort_keys=True)};" for k, v in consts.items()]
    return "\n".join(lines) + "\n"


def _view_error(exc: Exception) -> JSONResponse:
    if isinstance(exc, ApiRefused):
        return JSONResponse({"detail": exc.detail}, status_code=exc.status_code)
    return JSONResponse({"detail": f"could not build the 3D view: {exc}"}, status_code=422)


def mount_dashboard(app: FastAPI, settings: Any) -> None:
    """Add the dashboard pages, static assets and the viser 3D server to ``app``.

    The viser server is started and stopped by the callables appended to
    ``app.state.startup_hooks`` / ``app.state.shutdown_hooks`` (run by the app's lifespan).
    """
    templates = Jinja2Templates(directory=str(WEB_DIR / "templates"))
    viz = VizServer(host=getattr(settings, "host", "127.0.0.1"), port=settings.viser_port)
    app.state.viz = viz
    for name, hook in (("startup_hooks", viz.start), ("shutdown_hooks", viz.stop)):
        hooks = getattr(app.state, name, None)
        if hooks is None:
            hooks = []
            setattr(app.state, name, hooks)
        hooks.append(hook)

    app.mount("/static", StaticFiles(directory=str(WEB_DIR / "static")), name="static")
    router = APIRouter(include_in_schema=False)
    plotly_path = plotly_js_path()

    @router.get("/vendor/plotly.min.js")
    def plotly_js() -> FileResponse:
        """plotly.js from the installed package (no CDN)."""
        return FileResponse(
            plotly_path,
            media_type="text/javascript",
            headers={"Cache-Control": "public, max-age=86400"},
        )

    schema_js: list[str] = []  # built on first request (the routes are all added by then)

    @router.get("/api-schema.js")
    def api_schema() -> Response:
        """The API's published schemas and the robot's facts as an ES module, so the pages use
        the server's field names, statuses and constants instead of guessing them."""
        if not schema_js:
            schema_js.append(api_schema_module(app.openapi()))
        return Response(schema_js[0], media_type="text/javascript")

    def page(request: Request, template: str, **context: Any) -> HTMLResponse:
        return templates.TemplateResponse(
            request, template, {"viser_port": viz_port(), "page": template, **context}
        )

    def viz_port() -> int:
        return viz.port if viz.running else int(settings.viser_port)

    @router.get("/", response_class=HTMLResponse)
    def home() -> RedirectResponse:
        return RedirectResponse("/experiments", status_code=307)

    @router.get("/login", response_class=HTMLResponse)
    def login_page(request: Request) -> HTMLResponse:
        return page(request, "login.html")

    @router.get("/experiments", response_class=HTMLResponse)
    def experiments_page(request: Request) -> HTMLResponse:
        return page(request, "experiments.html")

    @router.get("/experiments/new", response_class=HTMLResponse)
    def new_experiment_page(request: Request) -> HTMLResponse:
        return page(request, "new_experiment.html")

    @router.get("/experiments/{experiment_id}", response_class=HTMLResponse)
    def experiment_page(request: Request, experiment_id: int) -> HTMLResponse:
        return page(request, "experiment.html", experiment_id=experiment_id)

    @router.get("/trials/{trial_id}", response_class=HTMLResponse)
    def trial_page(request: Request, trial_id: int) -> HTMLResponse:
        return page(request, "trial.html", trial_id=trial_id)

    @router.get("/viz/status")
    def viz_status() -> dict[str, Any]:
        """Whether the viser server runs, and on which port."""
        return {"running": viz.running, "port": viz_port()}

    @router.post("/viz/views")
    async def create_view(body: ViewRequest, request: Request) -> Any:
        """Register a 3D replay for one tab; returns its key and the viser port."""
        if body.trial_id is None:
            raise HTTPException(422, "trial_id is required (the trial to replay or preview)")
        if not viz.running:
            raise HTTPException(503, "the 3D viewer (viser) is not running on this server")
        auth = request.headers.get("Authorization")
        transport = httpx.ASGITransport(app=request.app)
        try:
            async with httpx.AsyncClient(transport=transport, base_url="http://dashboard") as c:
                if body.preview_job_id is not None:
                    primary, trial = await _preview_replay(c, auth, body)
                else:
                    primary, trial = await _trial_replay(c, auth, body.trial_id, "this trial")
                overlay = None
                if body.overlay_trial_id is not None:
                    overlay, _ = await _trial_replay(c, auth, body.overlay_trial_id, "overlay")
            key = await asyncio.to_thread(viz.add_view, primary, overlay)
        except (ApiRefused, ValueError, KeyError) as exc:
            return _view_error(exc)
        return {
            "key": key,
            "port": viz.port,
            "websocket_path": viz.websocket_path(key),
            # the same view through the main port (one forwarded port is enough)
            "proxy_url": "/viz/client/",
            "proxy_websocket_path": f"/viz/ws{viz.websocket_path(key)}",
            "label": primary.label,
            "overlay_label": overlay.label if overlay else None,
            "trial_id": trial.id,
        }

    async def _preview_replay(
        c: httpx.AsyncClient, auth: str | None, body: ViewRequest
    ) -> tuple[Replay, TrialRead]:
        """The preview job's rollout (exactly the trial's current schedule)."""
        job = await _get(c, f"/api/previews/{body.preview_job_id}", auth, PreviewJobRead)
        if job.status != "done":
            raise ValueError(f"preview {body.preview_job_id} is {job.status}, not done")
        trial = await _get(c, f"/api/trials/{body.trial_id}", auth, TrialRead)
        if job.trial_id != trial.id:
            raise ValueError(f"preview {body.preview_job_id} is of trial {job.trial_id}")
        if job.schedule_hash != trial.schedule_hash:
            raise ValueError("the trial's schedule changed since this preview; preview again")
        experiment = await _get(c, f"/api/experiments/{trial.experiment_id}", auth, ExperimentRead)
        task, preset = experiment.task, experiment.sim_preset
        recorded = _trajectory_qpos(job.trajectory)
        if recorded is None:
            recorded = await asyncio.to_thread(
                _simulate_qpos,
                task,
                preset,
                trial.pressure_schedule_pa,
                trial.release_step,
                experiment.command_hold,
            )
        label = f"trial {trial.index} (candidate, sim preview)"
        return Replay(task, recorded[0], recorded[1], label, preset), trial

    def upstream_host() -> str:
        host = str(settings.host)
        return "127.0.0.1" if host in ("0.0.0.0", "::", "") else host

    @router.get("/viz/client/{path:path}")
    async def viz_client(path: str, request: Request) -> Response:
        """The viser web client, proxied from the viser port (so one port serves it all)."""
        if not viz.running:
            raise HTTPException(503, "the 3D viewer (viser) is not running on this server")
        url = f"http://{upstream_host()}:{viz.port}/{path}"
        async with httpx.AsyncClient(timeout=30.0) as c:
            r = await c.get(url, params=dict(request.query_params))
        wanted = ("content-type", "cache-control")
        keep = {k: v for k, v in r.headers.items() if k.lower() in wanted}
        # the one thing our own pages frame: allowed by them alone (every other reply keeps
        # app.api.limits.SECURITY_HEADERS' frame-ancestors 'none' / DENY)
        keep["content-security-policy"] = VIZ_CLIENT_CSP
        keep["x-frame-options"] = "SAMEORIGIN"
        return Response(r.content, status_code=r.status_code, headers=keep)

    @router.websocket("/viz/ws/view/{key}")
    async def viz_socket(websocket: WebSocket, key: str) -> None:
        """A 3D view's websocket, relayed to the viser port both ways (its key is the secret)."""
        import websockets

        if not viz.running:
            await websocket.close(code=1013)
            return
        offered = list(websocket.scope.get("subprotocols") or [])
        url = f"ws://{upstream_host()}:{viz.port}{viz.websocket_path(key)}"
        try:
            upstream = await websockets.connect(
                url, subprotocols=offered or None, max_size=50 * 1024 * 1024, compression=None
            )
        except (OSError, websockets.exceptions.WebSocketException) as exc:
            log.warning("3D view %s: viser refused the relay: %s", key[:8], exc)
            await websocket.close(code=1011)
            return
        await websocket.accept(subprotocol=upstream.subprotocol)

        async def down() -> None:  # viser -> browser
            async for message in upstream:
                if isinstance(message, bytes):
                    await websocket.send_bytes(message)
                else:
                    await websocket.send_text(message)

        async def up() -> None:  # browser -> viser
            while True:
                message = await websocket.receive()
                if message["type"] == "websocket.disconnect":
                    return
                if message.get("bytes") is not None:
                    await upstream.send(message["bytes"])
                elif message.get("text") is not None:
                    await upstream.send(message["text"])

        tasks = [asyncio.create_task(down()), asyncio.create_task(up())]
        try:
            await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
        except WebSocketDisconnect:
            pass
        finally:
            for t in tasks:
                t.cancel()
            await upstream.close()
            with contextlib.suppress(RuntimeError):  # already closed by the browser
                await websocket.close()

    app.include_router(router)
