"""Helpers for the service benchmarks: a real uvicorn server over a migrated SQLite file."""

from __future__ import annotations

import contextlib
import subprocess
import threading
import time
from collections.abc import Callable, Iterator
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


def seed_database(data_dir: Path) -> tuple[str, str]:
    """Migrate ``data_dir/handful.db`` and add an operator ``bench``: (its URL, a token)."""
    data_dir.mkdir(parents=True, exist_ok=True)
    db_url = f"sqlite:///{(data_dir / 'handful.db').resolve()}"
    upgrade(db_url)
    db = Database(db_url)
    with db.write() as s:
        add_user(s, "bench", "operator")
        token = create_token(s, "bench")
    db.dispose()
    return db_url, token


def run_in_threads(n: int, work: Callable[[int], None]) -> float:
    """Run ``work(k)`` for k in 0..n-1 on n threads at once; seconds until all are done.

    The first exception raised in any thread is raised here (a failed post must not pass
    for a fast one).
    """
    failed: list[BaseException] = []

    def guarded(k: int) -> None:
        try:
            work(k)
        except BaseException as exc:
            failed.append(exc)

    threads = [threading.Thread(target=guarded, args=(k,)) for k in range(n)]
    t0 = time.perf_counter()
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    elapsed = time.perf_counter() - t0
    if failed:
        raise failed[0]
    return elapsed


@contextlib.contextmanager
def bench_server(data_dir: Path, env: dict[str, str] | None = None) -> Iterator[BenchServer]:
    """Migrate ``data_dir/handful.db``, add an operator, serve it on a free loopback port."""
    db_url, token = seed_database(data_dir)
    srv = ServerProcess(
        data_dir, free_port(), env={"HANDFUL_DASHBOARD_ENABLED": "0", **(env or {})}
    )
    srv.start(timeout_s=60.0)
    assert srv.proc is not None
    try:
        yield BenchServer(url=srv.url, db_url=db_url, token=token, proc=srv.proc)
    finally:
        srv.stop()
