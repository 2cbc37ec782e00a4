"""The viser 3D server: replays of trials and previews, one scene per browser tab.

How tabs get their own scene: the dashboard registers a *view* (a replay, optionally with a
second trial overlaid) and gets back an unguessable key. The tab's iframe loads viser's
bundled client with ``?websocket=ws://HOST:PORT/view/<key>``; the client opens its websocket
on that path, and on connect the server reads the path and builds the view in that client's
own scene (``client.scene``, ``client.gui``). So each tab sees only what it asked for, two tabs
on the same view each get their own play/pause state, and a reload rebuilds the view. Views
are kept in memory (the newest ``max_views``); an expired key shows a message in the viewer.

The viser port has no login: a view can only be reached through a key that an authenticated
dashboard request created, and it only holds motion data.
"""

from __future__ import annotations

import logging
import secrets
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import mujoco
import numpy as np

from app.viz.scene import ArmHandles, BodyPoses, body_poses, draw_arm, pose_arm

log = logging.getLogger(__name__)

VIEW_PATH_PREFIX = "/view/"
SPEEDS: dict[str, float] = {"0.1×": 0.1, "0.25×": 0.25, "0.5×": 0.5, "1×": 1.0, "2×": 2.0}
OVERLAY_TINT = (120, 170, 255)
OVERLAY_OPACITY = 0.35
TICK_S = 1.0 / 30.0


@dataclass(frozen=True)
class Replay:
    """One recorded or simulated motion to draw.

    Attributes:
        task: throw, hammer or tip_speed (picks the model: tip load, object, plate).
        time_s: (T,) increasing sample times, s.
        qpos: (T, nq) joint positions of the task's model.
        label: what the viewer shows, e.g. "trial 7 (candidate)".
        preset: the simulator preset whose model the qpos belong to.
    """

    task: str
    time_s: np.ndarray
    qpos: np.ndarray
    label: str
    preset: str = "reference"


@dataclass
class _Prepared:
    replay: Replay
    model: mujoco.MjModel
    poses: BodyPoses


@dataclass
class View:
    """A registered view: a primary replay and an optional overlaid one."""

    key: str
    title: str
    primary: _Prepared
    overlay: _Prepared | None
    created_at: float = field(default_factory=time.time)

    @property
    def duration_s(self) -> float:
        """Longest of the replays, s."""
        ends = [float(self.primary.replay.time_s[-1])]
        if self.overlay is not None:
            ends.append(float(self.overlay.replay.time_s[-1]))
        return max(ends)


@dataclass
class _Session:
    """One connected tab's playback state and handles."""

    client: Any
    view: View
    primary_handles: ArmHandles
    overlay_handles: ArmHandles | None
    overlay_root: Any | None
    time_slider: Any
    play_button: Any
    speed: Any
    t_s: float = 0.0
    playing: bool = False
    last_tick: float = field(default_factory=time.monotonic)


def _default_model_for(task: str, preset: str) -> mujoco.MjModel:
    from app.sim import build_model

    return build_model(task, preset=preset)


def frame_at(time_s: np.ndarray, t_s: float) -> int:
    """Index of the last sample at or before ``t_s`` (clamped to the replay)."""
    i = int(np.searchsorted(time_s, t_s, side="right")) - 1
    return min(max(i, 0), len(time_s) - 1)


class VizServer:
    """A viser server started with the app: registers views and serves them per tab.

    Args:
        host: interface to bind (127.0.0.1 in tests).
        port: TCP port; 0 picks a free one (read :attr:`port` after :meth:`start`).
        model_for: (task, preset) → compiled MjModel; defaults to ``app.sim.build_model``.
        max_views: how many views are kept; the oldest are dropped first.
    """

    def __init__(
        self,
        *,
        host: str = "127.0.0.1",
        port: int = 8081,
        model_for: Callable[[str, str], mujoco.MjModel] | None = None,
        max_views: int = 64,
    ) -> None:
        self.host = host
        self._requested_port = port
        self._model_for = model_for or _default_model_for
        self._models: dict[tuple[str, str], mujoco.MjModel] = {}
        self._views: OrderedDict[str, View] = OrderedDict()
        self._sessions: dict[int, _Session] = {}
        self._lock = threading.RLock()
        self._max_views = max_views
        self._server: Any = None
        self._ticker: threading.Thread | None = None
        self._stop = threading.Event()

    # --- lifecycle -----------------------------------------------------------------------------
    @property
    def port(self) -> int:
        """The bound port (after :meth:`start`)."""
        if self._server is None:
            raise RuntimeError("the viser server is not running")
        return int(self._server.get_port())

    @property
    def running(self) -> bool:
        """True between :meth:`start` and :meth:`stop`."""
        return self._server is not None

    def start(self) -> None:
        """Start viser (its own thread) and the playback ticker."""
        import viser

        if self._server is not None:
            return
        server = viser.ViserServer(host=self.host, port=self._requested_port, verbose=False)
        server.scene.set_up_direction("+z")
        # No share button: it opens a public tunnel through a third-party host.
        server.gui.configure_theme(show_share_button=False, show_logo=False)
        server.on_client_connect(self._on_connect)
        server.on_client_disconnect(self._on_disconnect)
        self._server = server
        self._stop.clear()
        self._ticker = threading.Thread(target=self._tick_loop, name="viz-ticker", daemon=True)
        self._ticker.start()
        log.info("viser 3D server on http://%s:%d", self.host, self.port)

    def stop(self) -> None:
        """Stop the ticker and the viser server."""
        self._stop.set()
        if self._ticker is not None:
            self._ticker.join(timeout=2.0)
            self._ticker = None
        if self._server is not None:
            self._server.stop()
            self._server = None
        with self._lock:
            self._sessions.clear()

    # --- views ---------------------------------------------------------------------------------
    def model(self, task: str, preset: str = "reference") -> mujoco.MjModel:
        """The compiled model for a task (cached)."""
        key = (task, preset)
        with self._lock:
            if key not in self._models:
                self._models[key] = self._model_for(task, preset)
            return self._models[key]

    def _prepare(self, replay: Replay) -> _Prepared:
        time_s = np.asarray(replay.time_s, dtype=np.float64)
        qpos = np.asarray(replay.qpos, dtype=np.float64)
        if time_s.ndim != 1 or time_s.shape[0] != qpos.shape[0]:
            raise ValueError(
                f"{replay.label}: time_s has shape {time_s.shape}, qpos {qpos.shape}; "
                "need (T,) and (T, nq)"
            )
        if time_s.shape[0] > 1 and not np.all(np.diff(time_s) > 0):
            raise ValueError(f"{replay.label}: time_s must increase")
        model = self.model(replay.task, replay.preset)
        poses = body_poses(model, qpos)
        clean = Replay(replay.task, time_s, qpos, replay.label, replay.preset)
        return _Prepared(clean, model, poses)

    def add_view(self, primary: Replay, overlay: Replay | None = None, *, title: str = "") -> str:
        """Register a view (forward kinematics done here, off the viewer's thread); its key.

        Raises:
            ValueError: qpos that does not fit the task's model, or bad times.
        """
        prepared = self._prepare(primary)
        prepared_overlay = self._prepare(overlay) if overlay is not None else None
        key = secrets.token_urlsafe(16)
        view = View(key, title or primary.label, prepared, prepared_overlay)
        with self._lock:
            self._views[key] = view
            while len(self._views) > self._max_views:
                self._views.popitem(last=False)
        return key

    def has_view(self, key: str) -> bool:
        """Whether ``key`` names a live view."""
        with self._lock:
            return key in self._views

    def sessions_for(self, key: str) -> int:
        """How many connected tabs show view ``key``."""
        with self._lock:
            return sum(1 for s in self._sessions.values() if s.view.key == key)

    def playback(self, key: str) -> list[tuple[bool, float]]:
        """(playing, time s) of each connected tab showing view ``key``."""
        with self._lock:
            return [(s.playing, s.t_s) for s in self._sessions.values() if s.view.key == key]

    @staticmethod
    def websocket_path(key: str) -> str:
        """The websocket path a tab opens to get view ``key``."""
        return f"{VIEW_PATH_PREFIX}{key}"

    # --- per-tab scenes ------------------------------------------------------------------------
    def _client_path(self, client: Any) -> str | None:
        """The websocket request path of a client (viser keeps the raw connection)."""
        ws = getattr(self._server, "_websock_server", None)
        connections = getattr(ws, "_live_connections", None) or {}
        conn = connections.get(client.client_id)
        request = getattr(conn, "request", None)
        return getattr(request, "path", None)

    def _on_connect(self, client: Any) -> None:
        path = self._client_path(client) or ""
        key = path.partition("?")[0]
        key = key[len(VIEW_PATH_PREFIX) :] if key.startswith(VIEW_PATH_PREFIX) else ""
        with self._lock:
            view = self._views.get(key)
        if view is None:
            client.gui.add_markdown(
                "**No replay here.** This view has expired or was never made: "
                "open Preview or the trial's 3D replay again from the dashboard."
            )
            return
        try:
            self._build_session(client, view)
        except Exception:  # a broken view must not take the viewer down; say so in it
            log.exception("could not build the 3D view %s", key)
            client.gui.add_markdown("**The 3D view failed to build**; see the server log.")

    def _build_session(self, client: Any, view: View) -> None:
        p = view.primary
        with client.atomic():
            client.scene.set_up_direction("+z")
            primary_handles = draw_arm(client.scene, "/primary", p.model, p.poses)
            overlay_handles = None
            overlay_root = None
            if view.overlay is not None:
                o = view.overlay
                overlay_root = client.scene.add_frame("/overlay", show_axes=False)
                overlay_handles = draw_arm(
                    client.scene,
                    "/overlay",
                    o.model,
                    o.poses,
                    opacity=OVERLAY_OPACITY,
                    tint=OVERLAY_TINT,
                    include_static=False,
                )
        client.camera.position = (0.9, 1.45, 1.05)
        client.camera.look_at = (-0.15, 0.15, 0.55)

        legend = f"**{view.primary.replay.label}**"
        if view.overlay is not None:
            legend += f"  \nblue, see-through: **{view.overlay.replay.label}**"
        client.gui.add_markdown(legend)
        play = client.gui.add_button("Play", icon=None)
        slider = client.gui.add_slider(
            "time (s)", min=0.0, max=round(view.duration_s, 3), step=0.01, initial_value=0.0
        )
        speed = client.gui.add_dropdown("speed", tuple(SPEEDS), initial_value="0.25×")
        session = _Session(
            client=client,
            view=view,
            primary_handles=primary_handles,
            overlay_handles=overlay_handles,
            overlay_root=overlay_root,
            time_slider=slider,
            play_button=play,
            speed=speed,
        )
        if view.overlay is not None:
            show = client.gui.add_checkbox("show overlay", initial_value=True)

            @show.on_update
            def _(_event: Any) -> None:
                if session.overlay_root is not None:
                    session.overlay_root.visible = bool(show.value)

        @play.on_click
        def _(_event: Any) -> None:
            with self._lock:
                if not session.playing and session.t_s >= view.duration_s - 1e-9:
                    session.t_s = 0.0
                session.playing = not session.playing
                session.last_tick = time.monotonic()
            play.label = "Pause" if session.playing else "Play"

        @slider.on_update
        def _(event: Any) -> None:
            if event.client is None:  # the ticker moved it
                return
            with self._lock:
                session.t_s = float(slider.value)
            self._show(session)

        with self._lock:
            self._sessions[client.client_id] = session

    def _on_disconnect(self, client: Any) -> None:
        with self._lock:
            self._sessions.pop(client.client_id, None)

    def _show(self, session: _Session) -> None:
        view = session.view
        with session.client.atomic():
            pose_arm(
                session.primary_handles,
                view.primary.poses,
                frame_at(view.primary.replay.time_s, session.t_s),
            )
            if view.overlay is not None and session.overlay_handles is not None:
                pose_arm(
                    session.overlay_handles,
                    view.overlay.poses,
                    frame_at(view.overlay.replay.time_s, session.t_s),
                )

    def _tick_loop(self) -> None:
        while not self._stop.wait(TICK_S):
            now = time.monotonic()
            with self._lock:
                playing = [s for s in self._sessions.values() if s.playing]
            for s in playing:
                try:
                    with self._lock:
                        dt = now - s.last_tick
                        s.last_tick = now
                        s.t_s += dt * SPEEDS.get(str(s.speed.value), 1.0)
                        if s.t_s >= s.view.duration_s:
                            s.t_s = s.view.duration_s
                            s.playing = False
                    self._show(s)
                    s.time_slider.value = round(s.t_s, 2)
                    if not s.playing:
                        s.play_button.label = "Play"
                except Exception:  # a tab that vanished mid-tick
                    log.debug("dropping a 3D session", exc_info=True)
                    with self._lock:
                        self._sessions.pop(s.client.client_id, None)
