"""Prepared statements store and read exactly what Connection.execute does (SQLite here;
tests/api/test_postgres.py runs the same checks on PostgreSQL)."""

from __future__ import annotations

from datetime import UTC, datetime

import pytest
from sqlalchemy import bindparam, insert, select, text, update
from sqlalchemy.exc import IntegrityError

from app.db.models import AuditLog, IdempotencyKey, Measurement
from app.db.prepared import Prepared
from app.db.session import Database
from app.service import lifecycle as lc
from app.service.measurements import _TRIAL_TO_MEASURE

AT = datetime(2026, 11, 22, 12, 30, 15, 123456, tzinfo=UTC)
AUDIT_ROW = {
    "at": AT,
    "actor": "olivia",
    "entity": "trial",
    "entity_id": "7",
    "experiment_id": None,
    "trial_id": None,
    "before": None,
    "after": "1.5",
    "detail": {"values": [1.5, 2.0], "source": "operator", "ok": True},
}


def check_same_as_execute(url: str) -> None:
    """Insert, update and select through both paths on ``url``; compare what is stored."""
    db = Database(url)
    try:
        audit = insert(AuditLog.__table__)
        with db.write() as s:
            conn = s.connection()
            conn.execute(audit, {**AUDIT_ROW, "action": "by_execute"})
            Prepared(audit).execute(conn, {**AUDIT_ROW, "action": "by_prepared"})
        with db.read() as s:
            by = {
                a.action: a for a in s.scalars(select(AuditLog).where(AuditLog.action.like("by_%")))
            }
            columns = AuditLog.__table__.columns.keys()
            for col in set(columns) - {"id", "action"}:
                assert getattr(by["by_prepared"], col) == getattr(by["by_execute"], col), col
            assert by["by_prepared"].at == AT and by["by_prepared"].detail == AUDIT_ROW["detail"]
            stored = s.execute(
                text("SELECT at, detail FROM audit_log WHERE action LIKE 'by_%' ORDER BY id")
            ).all()
            assert stored[0] == stored[1]  # the same bytes in the database, not just equal

        keys = IdempotencyKey.__table__
        key_row = {
            "scope": "measurements",
            "request_sha256": "0" * 64,
            "summary": "s",
            "receipt": None,
            "created_by": "olivia",
            "created_at": AT,
        }
        with db.write() as s:
            conn = s.connection()
            conn.execute(insert(keys), {**key_row, "key": "by_execute"})
            Prepared(insert(keys)).execute(conn, {**key_row, "key": "by_prepared"})
        change = update(keys).where(keys.c.key == bindparam("which"))
        change = change.values(created_at=bindparam("at"), receipt=bindparam("receipt"))
        new = {"at": datetime(2027, 1, 2, 3, 4, 5, 6, tzinfo=UTC), "receipt": {"n": [1, 2.5]}}
        with db.write() as s:
            conn = s.connection()
            conn.execute(change, {"which": "by_execute", **new})
            Prepared(change).execute(conn, {"which": "by_prepared", **new})
        with db.read() as s:
            stored = s.execute(
                text("SELECT request_sha256, receipt, created_at FROM idempotency_keys ORDER BY id")
            ).all()
            assert len(stored) == 2 and stored[0] == stored[1]
            both = s.scalars(select(IdempotencyKey)).all()
            assert [(k.created_at, k.receipt) for k in both] == [(new["at"], new["receipt"])] * 2

        with pytest.raises(IntegrityError), db.write() as s:  # SQLAlchemy's error, as execute
            Prepared(insert(keys)).execute(s.connection(), {**key_row, "key": "by_execute"})
        with db.read() as s:
            assert s.execute(text("SELECT count(*) FROM idempotency_keys")).scalar() == 2
    finally:
        db.dispose()


def test_prepared_statements_store_what_execute_stores(migrated_db):
    check_same_as_execute(migrated_db)


def test_a_select_with_literal_values_and_exists_gives_the_same_row(
    db, make_experiment, make_trial
):
    tid = make_trial(make_experiment(), status=lc.QUEUED)
    params = {"trial_id": tid, "scope": "measurements", "key": "none"}
    with db.write() as s:
        conn = s.connection()
        expected = tuple(conn.execute(_TRIAL_TO_MEASURE.stmt, params).one())
        got = _TRIAL_TO_MEASURE.execute(conn, params).fetchone()
    assert got == expected and got[2] == lc.QUEUED
    assert not got[5] and not got[6]  # no active lease ("active" is a literal), key unseen


def test_missing_values_are_named(db):
    repeat = Prepared(insert(Measurement.__table__))
    with db.write() as s:
        with pytest.raises(KeyError, match="created_at"):  # a column with a Python default
            repeat.execute(s.connection(), {"trial_id": 1, "value": 1.0, "unit": "m/s"})
        by_id = Prepared(select(Measurement.value).where(Measurement.id == bindparam("id")))
        with pytest.raises(KeyError, match="'id'"):
            by_id.execute(s.connection(), {})
