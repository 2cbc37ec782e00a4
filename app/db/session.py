"""Engine and session factories. SQLite: WAL, foreign keys on, busy timeout, explicit BEGIN.

SQLite runs with pysqlite's implicit transactions switched off and our own ``BEGIN``:
reads use a deferred ``BEGIN``; sessions from ``make_sessionmaker(engine, write=True)`` open
with ``BEGIN IMMEDIATE`` so a read-modify-write (claim a trial, add a measurement) holds the
write lock from its first read and two writers never act on the same stale snapshot.

``Database`` gives SQLite writes an engine of their own with a pool of one connection: the
process's writers queue for that connection (a condition variable, woken the moment it is
returned) instead of polling SQLite's lock through its busy handler, which sleeps 1, 2, 5,
10 … ms between tries. The busy timeout still covers writers in other processes (the CLI).
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from sqlalchemy import Engine, create_engine, event
from sqlalchemy.orm import Session, sessionmaker
from sqlalchemy.pool import QueuePool

from app.db.migrate import owner_only
from app.db.models import AuditLog

_BEGIN_OPTION = "handful_sqlite_begin"
BUSY_TIMEOUT_S = 30.0  # how long a writer waits for the lock (SQLite's, or the writer pool's)


def make_engine(
    url: str,
    *,
    echo: bool = False,
    sqlite_synchronous: str = "FULL",
    single_writer: bool = False,
    busy_timeout_s: float = BUSY_TIMEOUT_S,
) -> Engine:
    """An Engine for ``url``; SQLite files get WAL, foreign keys and a busy timeout (30 s).

    ``sqlite_synchronous``: ``FULL`` (default) fsyncs the WAL at every commit, so a committed
    measurement survives a power cut too; ``NORMAL`` survives a killed process but not a
    power cut, and commits several times faster. ``single_writer`` (SQLite only): a pool of
    one connection whose transactions all open with ``BEGIN IMMEDIATE``; a second writer in
    this process waits up to ``busy_timeout_s`` for it (then ``sqlalchemy.exc.TimeoutError``).
    """
    if sqlite_synchronous not in ("FULL", "NORMAL"):
        raise ValueError(f"sqlite_synchronous must be FULL or NORMAL, got {sqlite_synchronous!r}")
    if not url.startswith("sqlite"):
        return create_engine(url, echo=echo, pool_pre_ping=True)
    pool: dict[str, Any] = {}
    if single_writer:
        pool = {
            "poolclass": QueuePool,
            "pool_size": 1,
            "max_overflow": 0,
            "pool_timeout": busy_timeout_s,
            "execution_options": {_BEGIN_OPTION: "IMMEDIATE"},
        }
    engine = create_engine(url, echo=echo, connect_args={"check_same_thread": False}, **pool)

    @event.listens_for(engine, "connect")
    def _on_connect(dbapi_connection: Any, _record: Any) -> None:
        dbapi_connection.isolation_level = None  # we emit BEGIN ourselves (see module doc)
        cur = dbapi_connection.cursor()
        cur.execute(f"PRAGMA busy_timeout={busy_timeout_s * 1000:.0f}")
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
    """A read and a write session factory; on SQLite, writes have their own one-connection
    engine, ``write_engine`` (see the module docstring)."""

    def __init__(
        self, url: str, *, sqlite_synchronous: str = "FULL", busy_timeout_s: float = BUSY_TIMEOUT_S
    ) -> None:
        self.url = url
        owner_only(url)  # an older data folder's world-readable file, too
        opts: dict[str, Any] = {
            "sqlite_synchronous": sqlite_synchronous,
            "busy_timeout_s": busy_timeout_s,
        }
        self.engine = make_engine(url, **opts)
        self._read = make_sessionmaker(self.engine)
        if url.startswith("sqlite"):
            self.write_engine = make_engine(url, single_writer=True, **opts)
            self._write = make_sessionmaker(self.write_engine)
        else:  # PostgreSQL: concurrent writers, row locks
            self.write_engine = self.engine
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
        """A session holding the write lock; the one place a write transaction commits: once,
        on success. An error rolls it back, unless its ``keep_changes`` says otherwise (a
        LeaseLost keeps the sweep that found it). Service functions flush, never commit."""
        with self._write() as session:
            try:
                yield session
            except BaseException as exc:
                if getattr(exc, "keep_changes", False):
                    session.commit()
                else:
                    session.rollback()
                raise
            session.commit()

    def dispose(self) -> None:
        """Close all pooled connections."""
        self.engine.dispose()
        self.write_engine.dispose()
