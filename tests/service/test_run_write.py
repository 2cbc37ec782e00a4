"""run_write: a short write runs on the event loop when SQLite's writer is free, in a pool
thread when another writer holds it (the loop keeps serving meanwhile)."""

from __future__ import annotations

import asyncio
import threading
import time

from sqlalchemy import text

from app.api.deps import run_write


def _notes(s) -> str:
    return s.execute(text("SELECT notes FROM experiments")).scalar_one()


def test_a_short_write_runs_on_the_loop_when_the_writer_is_free(db, make_experiment):
    make_experiment()

    async def main() -> tuple[int, str]:
        def work(s) -> tuple[int, str]:
            s.execute(text("UPDATE experiments SET notes = 'inline'"))
            return threading.get_ident(), _notes(s)

        return await run_write(db, work)

    ident, seen = asyncio.run(main())
    assert ident == threading.get_ident() and seen == "inline"  # no hop to a pool thread
    with db.read() as s:
        assert _notes(s) == "inline"  # committed
    assert db.writer_idle()


def test_a_write_waits_in_a_thread_while_another_writer_holds_the_lock(db, make_experiment):
    make_experiment()
    held, release = threading.Event(), threading.Event()

    def holder() -> None:
        with db.write() as s:
            s.execute(text("UPDATE experiments SET notes = 'holder'"))
            held.set()
            release.wait(10)

    t = threading.Thread(target=holder)
    t.start()
    held.wait(10)
    assert not db.writer_idle()

    async def main() -> tuple[int, str, int]:
        ticks = 0

        async def tick() -> None:
            nonlocal ticks
            while True:
                ticks += 1
                await asyncio.sleep(0.01)

        ticker = asyncio.create_task(tick())
        asyncio.get_running_loop().call_later(0.3, release.set)
        ident, seen = await run_write(db, lambda s: (threading.get_ident(), _notes(s)))
        ticker.cancel()
        return ident, seen, ticks

    t0 = time.monotonic()
    ident, seen, ticks = asyncio.run(main())
    t.join()
    assert ident != threading.get_ident()  # it waited in a pool thread ...
    assert seen == "holder"  # ... until the holder committed
    assert time.monotonic() - t0 >= 0.3 and ticks >= 10  # and the loop kept running


def test_no_write_transaction_ends_on_the_event_loop_but_run_writes(
    migrated_db, tmp_path, monkeypatch
):
    """Every write route ends its transaction in the thread that did the work (or inline in
    ``run_write``): one whose commit waited for the event loop could hold the write
    connection while ``run_write``, on that loop, waits for it."""
    import gc
    from contextlib import contextmanager

    from fastapi.testclient import TestClient

    import app.api.deps as deps
    from app.api.main import create_app
    from app.config import Settings

    from ..conftest import seed_users

    tokens = seed_users(migrated_db)
    settings = Settings(data_dir=tmp_path / "d", database_url=migrated_db, dashboard_enabled=False)
    app = create_app(settings)
    db = app.state.db
    ended: list[tuple[bool, bool]] = []  # (on an event loop, inside run_write's inline path)
    inline = threading.local()
    real_write, real_inline = db.write, deps._write

    @contextmanager
    def write():
        try:
            with real_write() as s:
                yield s
        finally:  # committed or rolled back: where did that happen?
            try:
                asyncio.get_running_loop()
                on_loop = True
            except RuntimeError:
                on_loop = False
            ended.append((on_loop, getattr(inline, "on", False)))

    def marked(database, work):
        inline.on = True
        try:
            return real_inline(database, work)
        finally:
            inline.on = False

    monkeypatch.setattr(db, "write", write)
    monkeypatch.setattr(deps, "_write", marked)
    op = {"Authorization": f"Bearer {tokens['operator']}"}
    spec = {"name": "x", "task": "tip_speed", "levels": 3, "method": "random"}
    claim = {"worker_id": "w", "target": "sim", "max_trials": 1}
    measure = {"repeats": [{"value": 1.0, "unit": "m/s"}]}
    calls = [
        ("POST", "/api/experiments", spec, op),
        ("PATCH", "/api/experiments/1", {"notes": "n"}, op),
        ("POST", "/api/experiments/1/trials", {"theta": [0.5] * 10, "note": ""}, op),
        ("POST", "/api/experiments/1/suggest", {"n": 2}, op),
        ("POST", "/api/workers/claim", claim, {"Authorization": f"Bearer {tokens['worker']}"}),
        ("POST", "/api/trials/2/measurements", measure, {**op, "Idempotency-Key": "k"}),
        ("POST", "/api/trials/3/abandon", {"reason": "r"}, op),
        ("POST", "/api/trials/2/fail", {"reason": "r"}, op),  # refused: completed
        ("POST", "/api/auth/login", {"username": "operator", "password": "wrong"}, {}),
    ]
    with TestClient(app) as client:
        for method, path, body, headers in calls:
            n = len(ended)
            r = client.request(method, path, json=body, headers=headers)
            assert r.status_code < 500, (path, r.text)
            assert len(ended) > n, f"{method} {path} opened no write session"
            assert all(inline_ or not loop for loop, inline_ in ended[n:]), (
                f"{method} {path} ended a write transaction on the event loop"
            )
            assert db.writer_idle()
    assert (True, True) in ended  # the measurement post did run inline
    gc.unfreeze()
