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
