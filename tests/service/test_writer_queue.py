"""SQLite writers in one process queue for a single write connection (no busy-handler polling)."""

from __future__ import annotations

import threading
import time

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient
from sqlalchemy import select, text
from sqlalchemy.exc import OperationalError
from sqlalchemy.exc import TimeoutError as PoolTimeout

from app.api import errors
from app.db.models import Measurement, Trial
from app.db.session import Database
from app.service import lifecycle as lc
from app.service.measurements import add_measurements
from app.service.schemas import MeasurementsIn

from .conftest import OPERATOR


def test_concurrent_posts_to_one_trial_all_land(db, make_experiment, make_trial):
    """8 threads x 10 posts on the same trial: every repeat stored, the count and mean exact."""
    tid = make_trial(make_experiment(), status=lc.QUEUED)
    failures: list[BaseException] = []

    def post(k: int) -> None:
        try:
            for i in range(10):
                body = MeasurementsIn(repeats=[{"value": float(k * 10 + i), "unit": "m/s"}])
                with db.write() as s:
                    add_measurements(s, tid, body, idempotency_key=f"{k}-{i}", actor=OPERATOR)
        except BaseException as exc:
            failures.append(exc)

    threads = [threading.Thread(target=post, args=(k,)) for k in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert failures == []
    with db.read() as s:
        values = s.scalars(select(Measurement.value).where(Measurement.trial_id == tid)).all()
        trial = s.get(Trial, tid)
        assert sorted(values) == [float(v) for v in range(80)]
        assert trial.n_measurements == 80 and trial.objective == pytest.approx(39.5, rel=1e-12)
        assert trial.status == lc.COMPLETED


def test_a_second_writer_waits_for_the_first_and_then_sees_its_write(db, make_experiment):
    make_experiment()
    holding, order = threading.Event(), []

    def first() -> None:
        with db.write() as s:
            s.execute(text("UPDATE experiments SET notes = 'first'"))
            holding.set()
            time.sleep(0.3)
            order.append("first commits")

    def second() -> None:
        holding.wait()
        with db.write() as s:  # takes the write connection at its first statement
            seen = s.execute(text("SELECT notes FROM experiments")).scalar_one()
            order.append(f"second sees {seen}")

    threads = [threading.Thread(target=first), threading.Thread(target=second)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert order == ["first commits", "second sees first"]


def test_a_writer_that_waits_too_long_gets_a_timeout_and_nothing_is_stored(
    migrated_db, make_experiment
):
    make_experiment()
    db = Database(migrated_db, busy_timeout_s=0.2)
    try:
        with db.write() as holder:
            holder.execute(text("UPDATE experiments SET notes = 'held'"))
            # the writer queue times out (not SQLite's busy handler, which would poll)
            with pytest.raises(PoolTimeout), db.write() as s:
                s.execute(text("UPDATE experiments SET notes = 'second'"))
        with db.read() as s:
            assert s.execute(text("SELECT notes FROM experiments")).scalar_one() == "held"
    finally:
        db.dispose()


def test_a_busy_database_is_a_503_that_says_to_retry():
    app = FastAPI()
    errors.install(app)

    @app.post("/queue")
    def queue() -> None:
        raise PoolTimeout("QueuePool limit of size 1 overflow 0 reached")

    @app.post("/locked")
    def locked() -> None:
        raise OperationalError("BEGIN IMMEDIATE", {}, Exception("database is locked"))

    @app.post("/broken")
    def broken() -> None:
        raise OperationalError("SELECT", {}, Exception("no such table: trials"))

    with TestClient(app, raise_server_exceptions=False) as client:
        for path in ("/queue", "/locked"):
            r = client.post(path)
            assert r.status_code == 503, path
            assert r.json()["code"] == "database_busy" and "retry" in r.json()["detail"]
            assert r.headers["retry-after"] == "1"
        assert client.post("/broken").status_code == 500  # not every database error is "busy"
