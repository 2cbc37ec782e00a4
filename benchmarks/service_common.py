"""Helpers for the service benchmarks: a real uvicorn server over a migrated SQLite file."""

from __future__ import annotations

import contextlib
import os
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
class BenchServer:
    url: str
    db_url: str
    token: str
    proc: subprocess.Popen[bytes]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@contextlib.contextmanager
def bench_server(data_dir: Path, env: dict[str, str] | None = None) -> Iterator[BenchServer]:
    """Migrate ``data_dir/handful.db``, add an operator, serve it on a free loopback port."""
    data_dir.mkdir(parents=True, exist_ok=True)
    db_url = f"sqlite:///{(data_dir / 'handful.db').resolve()}"
    upgrade(db_url)
    db = Database(db_url)
    with db.write() as s:
        add_user(s, "bench", "operator")
        token = create_token(s, "bench")
    db.dispose()
    port = _free_port()
    full_env = {
        **os.environ,
        "HANDFUL_DATA_DIR": str(data_dir),
        "HANDFUL_DASHBOARD_ENABLED": "0",
        **(env or {}),
    }
    log = open(data_dir / "server.log", "ab")  # noqa: SIM115
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "uvicorn",
            "--factory",
            "app.api.main:create_app",
            "--host",
            "127.0.0.1",
            "--port",
            str(port),
            "--log-level",
            "warning",
        ],
        cwd=REPO,
        env=full_env,
        stdout=log,
        stderr=subprocess.STDOUT,
    )
    url = f"http://127.0.0.1:{port}"
    try:
        for _ in range(600):
            with contextlib.suppress(httpx.HTTPError):
                if httpx.get(url + "/health", timeout=1).status_code == 200:
                    break
            if proc.poll() is not None:
                raise RuntimeError("server exited; see " + str(data_dir / "server.log"))
            time.sleep(0.1)
        yield BenchServer(url=url, db_url=db_url, token=token, proc=proc)
    finally:
        proc.terminate()
        proc.wait(timeout=30)
        log.close()
