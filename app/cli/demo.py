"""`handful demo`: the server, a sim worker and a stand-in robot, with two live experiments.

Starts three processes (``handful serve``, ``handful worker sim``, ``handful worker hardware
--driver standin``), creates the demo users and tokens, a sim throwing experiment and a hardware
tip-speed experiment with the paper's limits, keeps both fed with suggestions, prints the
dashboard URL and the operator's login, and runs until Ctrl-C (or ``--exit-after``), then shuts
everything down cleanly. Hardware trials wait for the operator's confirmation in the dashboard
(``--auto-confirm`` confirms them itself, for unattended runs on the stand-in).
"""

from __future__ import annotations

import contextlib
import logging
import os
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Annotated, Any

import typer

from app.devserver import free_port, wait_healthy

log = logging.getLogger("handful.demo")

OPERATOR, WORKER = "demo-operator", "demo-worker"
SIM_EXPERIMENT = {
    "name": "demo: throwing (sim)",
    "task": "throw",
    "target": "sim",
    "levels": 5,
    "method": "bo-lei-default",
    "budget": 100,
    "sim_preset": "fast",
    "seed": 1,
    "notes": "Started by `handful demo`: the sim worker runs these as they are suggested.",
}
HARDWARE_EXPERIMENT = {
    "name": "demo: tip speed (stand-in robot)",
    "task": "tip_speed",
    "target": "hardware",
    "levels": 5,
    "method": "bo-lei-default",
    "n_initial": 12,
    "budget": 72,
    "limits": {"nominal_pa": 100_000.0, "max_step_pa": 30_000.0, "source_pa": 205_000.0},
    "seed": 2,
    "notes": "Started by `handful demo`: confirm each trial; the stand-in robot then runs it.",
}


def _port_free(port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
        return True


def _users_and_tokens(data_dir: Path) -> tuple[str, str, str | None]:
    """Create (or reuse) the demo operator and worker; fresh tokens each run.

    Returns (operator token, worker token, operator password or None if the user existed).
    """
    from app.config import Settings
    from app.db.migrate import upgrade
    from app.db.session import Database
    from app.service.auth import add_user, create_token
    from app.service.errors import ServiceError

    settings = Settings(data_dir=data_dir)
    data_dir.mkdir(parents=True, exist_ok=True)
    upgrade(settings.db_url)
    db = Database(settings.db_url)
    password: str | None = secrets.token_urlsafe(9)
    try:
        for name, role in ((OPERATOR, "operator"), (WORKER, "worker")):
            try:
                with db.write() as s:
                    add_user(s, name, role, password=password if role == "operator" else None)
            except ServiceError:
                if role == "operator":
                    password = None  # kept from an earlier demo run
        with db.write() as s:
            operator_token = create_token(s, OPERATOR, label="demo")
            worker_token = create_token(s, WORKER, label="demo")
    finally:
        db.dispose()
    return operator_token, worker_token, password


class _Processes:
    """The demo's child processes, each in its own session (Ctrl-C reaches only the demo)."""

    def __init__(self, log_dir: Path) -> None:
        self.log_dir = log_dir
        self.procs: dict[str, subprocess.Popen[bytes]] = {}

    def start(self, name: str, args: list[str], env: dict[str, str]) -> None:
        log_file = open(self.log_dir / f"{name}.log", "ab")  # noqa: SIM115 (the child owns it)
        self.procs[name] = subprocess.Popen(
            [sys.executable, "-m", "app.cli", *args],
            stdout=log_file,
            stderr=subprocess.STDOUT,
            env={**os.environ, **env, "PYTHONUNBUFFERED": "1"},
            start_new_session=True,
        )
        log_file.close()

    def dead(self) -> list[str]:
        return [n for n, p in self.procs.items() if p.poll() is not None]

    def stop(self, names: list[str], timeout_s: float) -> None:
        """SIGTERM `names` (workers finish their trial), wait, SIGKILL stragglers."""
        for n in names:
            p = self.procs.get(n)
            if p is not None and p.poll() is None:
                p.send_signal(signal.SIGTERM)
        deadline = time.monotonic() + timeout_s
        for n in names:
            p = self.procs.get(n)
            if p is None:
                continue
            try:
                p.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                log.warning("%s did not stop in %.0f s; killing it", n, timeout_s)
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(p.pid, signal.SIGKILL)
                p.wait()


def _ensure_experiments(api: Any) -> tuple[int, int]:
    """The demo's sim and hardware experiments: reuse them from an earlier run, else create."""
    found = {e["name"]: e["id"] for e in api.list_experiments()}
    ids = []
    for spec in (SIM_EXPERIMENT, HARDWARE_EXPERIMENT):
        ids.append(found.get(spec["name"]) or api.create_experiment(**spec)["id"])
    return ids[0], ids[1]


def _autopilot(
    api: Any, sim_id: int, hw_id: int, *, auto_confirm: bool, stop: threading.Event
) -> None:
    """Keep a couple of sim trials queued and one hardware trial waiting, within budgets."""
    from app.client import HandfulAPIError

    pending = {"proposed", "awaiting_confirmation", "queued", "running"}
    while not stop.is_set():
        try:
            for exp_id, keep in ((sim_id, 2), (hw_id, 1)):
                exp = api.get_experiment(exp_id)
                counts = exp["status_counts"]
                waiting = sum(counts.get(s, 0) for s in pending)
                left = (exp["budget"] or 10**9) - exp["n_trials"]
                if exp["status"] == "active" and waiting < keep and left > 0:
                    api.suggest(exp_id, n=min(keep - waiting, left))
            if auto_confirm:
                for t in api.list_trials(hw_id, status="awaiting_confirmation"):
                    api.preview_and_confirm(t)
        except HandfulAPIError as exc:
            log.warning("autopilot: %s", exc)
        except Exception as exc:  # the server restarting, a timeout: try again shortly
            log.warning("autopilot: %s: %s", exc.__class__.__name__, exc)
        stop.wait(1.0)


def demo(
    port: Annotated[int, typer.Option(help="HTTP port of the server and dashboard")] = 8000,
    data_dir: Annotated[
        Path, typer.Option(help="demo data folder (database, trajectories, stand-in state)")
    ] = Path("data/demo"),
    fresh: Annotated[bool, typer.Option(help="wipe the demo data folder first")] = False,
    max_parallel: Annotated[
        int | None, typer.Option(help="sim worker processes (default: all cores)")
    ] = None,
    realtime: Annotated[
        bool, typer.Option(help="the stand-in robot takes 5 s per trial, like the real one")
    ] = True,
    auto_confirm: Annotated[
        bool, typer.Option(help="confirm hardware trials automatically (stand-in only)")
    ] = False,
    exit_after: Annotated[
        float | None, typer.Option(help="shut down after this many seconds (smoke tests)")
    ] = None,
) -> None:
    """Run the server, one sim worker and one stand-in robot with two demo experiments."""
    from app.client import HandfulClient

    logging.basicConfig(level=logging.INFO, format="%(asctime)s demo: %(message)s")
    logging.getLogger("httpx").setLevel(logging.WARNING)
    if fresh and data_dir.exists():
        shutil.rmtree(data_dir)
    if not _port_free(port):
        typer.echo(f"error: port {port} on 127.0.0.1 is taken; pass --port", err=True)
        raise typer.Exit(2)
    operator_token, worker_token, password = _users_and_tokens(data_dir)
    log_dir = data_dir / "logs"
    log_dir.mkdir(parents=True, exist_ok=True)
    url = f"http://127.0.0.1:{port}"
    server_env = {
        "HANDFUL_DATA_DIR": str(data_dir),
        "HANDFUL_VISER_PORT": str(free_port()),
        "HANDFUL_LEASE_SECONDS": "30",
    }
    procs = _Processes(log_dir)
    stop = threading.Event()
    interrupted = threading.Event()

    def on_signal(signum: int, _frame: Any) -> None:
        interrupted.set()

    old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    code = 0
    autopilot: threading.Thread | None = None
    try:
        procs.start(
            "server",
            ["serve", "--host", "127.0.0.1", "--port", str(port), "--data-dir", str(data_dir)],
            server_env,
        )
        wait_healthy(url, procs.procs["server"], timeout_s=120.0, log_path=log_dir / "server.log")
        api = HandfulClient(url, token=operator_token, timeout=120.0)
        sim_id, hw_id = _ensure_experiments(api)
        worker_args = ["--server", url]  # the token goes in the environment, not in ps
        procs.start(
            "sim-worker",
            [
                *("worker", "sim", *worker_args, "--worker-id", "demo-sim"),
                *(("--max-parallel", str(max_parallel)) if max_parallel else ()),
            ],
            {"HANDFUL_TOKEN": worker_token},
        )
        procs.start(
            "standin-worker",
            [
                *("worker", "hardware", *worker_args, "--worker-id", "demo-standin"),
                *("--driver", "standin", "-o", f"realtime={str(realtime).lower()}"),
                *("-o", f"state_file={data_dir / 'standin_state.json'}", "-o", "seed=2"),
            ],
            {"HANDFUL_TOKEN": worker_token},
        )
        autopilot = threading.Thread(
            target=_autopilot,
            args=(api, sim_id, hw_id),
            kwargs={"auto_confirm": auto_confirm, "stop": stop},
            daemon=True,
        )
        autopilot.start()
        login = f"{OPERATOR} / {password}" if password else f"{OPERATOR} (password unchanged)"
        typer.echo(
            "\nhandful demo is running\n"
            f"  dashboard      {url}/experiments/{sim_id}   (hardware: {url}/experiments/{hw_id})\n"
            f"  login          {login}\n"
            f"  operator token {operator_token}\n"
            f"  logs           {log_dir}/\n"
            "Confirm hardware trials in the dashboard; the stand-in robot runs them. "
            "Ctrl-C stops everything.\n"
        )
        started = time.monotonic()
        while not interrupted.is_set():
            if dead := procs.dead():
                typer.echo(f"error: {', '.join(dead)} exited; see {log_dir}/", err=True)
                code = 1
                break
            if exit_after is not None and time.monotonic() - started >= exit_after:
                break
            interrupted.wait(0.5)
    except RuntimeError as exc:
        typer.echo(f"error: {exc}; see {log_dir}/server.log", err=True)
        code = 1
    finally:
        typer.echo("stopping: workers finish their trial, then the server stops")
        stop.set()
        if autopilot is not None:
            autopilot.join(timeout=10.0)
        procs.stop(["sim-worker", "standin-worker"], timeout_s=60.0)
        procs.stop(["server"], timeout_s=30.0)
        for s, h in old.items():
            signal.signal(s, h)
    if code:
        raise typer.Exit(code)
    typer.echo("demo stopped cleanly")


def register(app: typer.Typer) -> None:
    """Add `demo` to the root app."""
    app.command("demo")(demo)
