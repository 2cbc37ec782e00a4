"""Engine and session factories. SQLite: WAL, foreign keys on, busy timeout, explicit BEGIN.

SQLite runs with pysqlite's implicit transactions switched off and our own ``BEGIN``:
reads use a deferred ``BEGIN``; sessions from ``make_sessionmaker(engine, write=True)`` open
with ``BEGIN IMMEDIATE`` so a read-modify-write (claim a trial, add a measurement) holds the
write lock from its first read and two writers never act on the same stale snapshot.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from sqlalchemy import Engine, create_engine, event
from sqlalchemy.orm import Session, sessionmaker

from app.db.models import AuditLog

_BEGIN_OPTION = "handful_sqlite_begin"


def make_engine(url: str, *, echo: bool = False, sqlite_synchronous: str = "FULL") -> Engine:
    """An Engine for ``url``; SQLite files get WAL, foreign keys and a 30 s busy timeout.

    ``sqlite_synchronous``: ``FULL`` (default) fsyncs the WAL at every commit, so a committed
    measurement survives a power cut too; ``NORMAL`` survives a killed process but not a
    power cut, and commits several times faster.
    """
    if sqlite_synchronous not in ("FULL", "NORMAL"):
        raise ValueError(f"sqlite_synchronous must be FULL or NORMAL, got {sqlite_synchronous!r}")
    if not url.startswith("sqlite"):
        return create_engine(url, echo=echo, pool_pre_ping=True)
    engine = create_engine(url, echo=echo, connect_args={"check_same_thread": False})

    @event.listens_for(engine, "connect")
    def _on_connect(dbapi_connection: Any, _record: Any) -> None:
        dbapi_connection.isolation_level = None  # we emit BEGIN ourselves (see module doc)
        cur = dbapi_connection.cursor()
        cur.execute("PRAGMA busy_timeout=30000")
        cur.execute("PRAGMA journal_mode=WAL")
        cur.execute(f"PRAGMA synchronous={sqlite_synchronous}")
        cur.execute("PRAGMA foreign_keys=ON")
        cur.close()

    @event.listens_for(engine, "begin")
    def _on_begin(conn: Any) -> None:
        mode = conn.get_execution_options().get(_BEGIN_OPTION, "")
        conn.exec_driver_sql(f"BEGIN {mode}".strip())

    return engine


def make_sessionmaker(engine: Engine, *, write: bool = False) -> sessionmaker[Session]:
    """Session factory; ``write=True`` takes SQLite's write lock at BEGIN (no stale snapshot)."""
    bind = engine.execution_options(**{_BEGIN_OPTION: "IMMEDIATE"}) if write else engine
    return sessionmaker(bind=bind, expire_on_commit=False)


@event.listens_for(Session, "before_flush")
def _audit_is_append_only(session: Session, _ctx: Any, _instances: Any) -> None:
    for obj in (*session.dirty, *session.deleted):
        if isinstance(obj, AuditLog):
            raise RuntimeError("the audit log is append-only: rows cannot change or be deleted")


class Database:
    """One engine with a read and a write session factory (see the module docstring)."""

    def __init__(self, url: str, *, sqlite_synchronous: str = "FULL") -> None:
        self.url = url
        self.engine = make_engine(url, sqlite_synchronous=sqlite_synchronous)
        self._read = make_sessionmaker(self.engine)
        self._write = make_sessionmaker(self.engine, write=True)

    @contextmanager
    def read(self) -> Iterator[Session]:
        """A session for reading; whatever it did is rolled back at the end."""
        with self._read() as session:
            try:
                yield session
            finally:
                session.rollback()

    @contextmanager
    def write(self) -> Iterator[Session]:
        """A session holding the write lock; committed on success, rolled back on error."""
        with self._write() as session:
            try:
                yield session
                if session.in_transaction():  # the caller may have committed already
                    session.commit()
            except BaseException:
                session.rollback()
                raise

    def dispose(self) -> None:
        """Close all pooled connections."""
        self.engine.dispose()
