"""Helpers for the worker benchmarks: a real server and real `handful worker` processes."""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import httpx

from app.db.migrate import upgrade
from app.db.session import Database
from app.service.auth import add_user, create_token

REPO = Path(__file__).resolve().parents[1]


@dataclass
class Server:
    """A uvicorn subprocess over a migrated SQLite file, with operator and worker tokens."""

    url: str
    operator_token: str
    worker_token: str
    data_dir: Path
    proc: subprocess.Popen[bytes]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@contextlib.contextmanager
def server(data_dir: Path, env: dict[str, str] | None = None) -> Iterator[Server]:
    """Serve a fresh database under ``data_dir`` on a free loopback port (dashboard off)."""
    data_dir.mkdir(parents=True, exist_ok=True)
    db_url = f"sqlite:///{(data_dir / 'handful.db').resolve()}"
    upgrade(db_url)
    db = Database(db_url)
    with db.write() as s:
        add_user(s, "bench-operator", "operator")
        add_user(s, "bench-worker", "worker")
        op, wk = create_token(s, "bench-operator"), create_token(s, "bench-worker")
    db.dispose()
    port = free_port()
    log = open(data_dir / "server.log", "ab")  # noqa: SIM115 (the child owns it)
    proc = subprocess.Popen(
        [
            *(sys.executable, "-m", "uvicorn", "--factory", "app.api.main:create_app"),
            *("--host", "127.0.0.1", "--port", str(port), "--log-level", "warning"),
        ],
        cwd=REPO,
        env={
            **os.environ,
            "HANDFUL_DATA_DIR": str(data_dir),
            "HANDFUL_DASHBOARD_ENABLED": "0",
            **(env or {}),
        },
        stdout=log,
        stderr=subprocess.STDOUT,
    )
    log.close()
    url = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 120
        while True:
            with contextlib.suppress(httpx.HTTPError):
                if httpx.get(url + "/health", timeout=1).status_code == 200:
                    break
            if proc.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"server did not start; see {data_dir / 'server.log'}")
            time.sleep(0.1)
        yield Server(url, op, wk, data_dir, proc)
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()


def start_worker(srv: Server, kind: str, *args: str, log_name: str) -> subprocess.Popen[bytes]:
    """Start `python -m app.cli worker KIND` against ``srv`` in its own process group."""
    log = open(srv.data_dir / log_name, "ab")  # noqa: SIM115 (the child owns it)
    proc = subprocess.Popen(
        [
            *(sys.executable, "-m", "app.cli", "worker", kind, "--server", srv.url),
            *("--token", srv.worker_token, "--poll", "0.1", *args),
        ],
        cwd=REPO,
        stdout=log,
        stderr=subprocess.STDOUT,
        start_new_session=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    log.close()
    return proc


def stop_worker(proc: subprocess.Popen[bytes]) -> None:
    """SIGTERM, then SIGKILL the group if it lingers."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


def cpu_s(*, pgid: int | None = None, pid: int | None = None) -> float:
    """CPU seconds (user + system) used so far by a live process or process group."""
    tick = os.sysconf("SC_CLK_TCK")
    total = 0.0
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        # after "pid (comm)": state ppid pgrp session ... utime(14) stime(15), 1-based overall
        if (pgid is not None and int(fields[2]) == pgid) or (
            pgid is None and int(entry.name) == pid
        ):
            total += (int(fields[11]) + int(fields[12])) / tick
    return total
