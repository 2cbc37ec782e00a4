"""Helpers for the service benchmarks: a real uvicorn server over a migrated SQLite file."""

from __future__ import annotations

import contextlib
import subprocess
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from app.db.migrate import upgrade
from app.db.session import Database
from app.devserver import ServerProcess, free_port
from app.service.auth import add_user, create_token


@dataclass
class BenchServer:
    url: str
    db_url: str
    token: str
    proc: subprocess.Popen[bytes]


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
    srv = ServerProcess(
        data_dir, free_port(), env={"HANDFUL_DASHBOARD_ENABLED": "0", **(env or {})}
    )
    srv.start(timeout_s=60.0)
    assert srv.proc is not None
    try:
        yield BenchServer(url=srv.url, db_url=db_url, token=token, proc=srv.proc)
    finally:
        srv.stop()
