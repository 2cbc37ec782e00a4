"""Core statements compiled once per dialect and run on the driver's cursor.

``Connection.execute`` spends most of a small statement's time in SQLAlchemy's execution
machinery (cache lookup, execution context, events, result set-up), several times what
SQLite takes to run it. The service's most frequent write, a measurement post, is seven
such statements; ``Prepared`` runs them with that machinery cut out and nothing else changed:

- the SQL is SQLAlchemy's own, compiled for the connection's dialect (SQLite, PostgreSQL);
- every bound value goes through its column type's bind processor (timestamps, JSON), so
  rows are stored exactly as ``Connection.execute`` would store them;
- driver errors are re-raised as SQLAlchemy's (``IntegrityError``, ``OperationalError``);
- it runs in the connection's current transaction (begun, and committed, by its owner).

Not applied on this path: Python-side column defaults (pass every value; a missing one is a
``KeyError`` naming it), result processing (use it for plain numbers, strings and EXISTS
flags), and engine events (``echo`` does not log these statements).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

from sqlalchemy.engine import Connection, Dialect
from sqlalchemy.exc import DBAPIError
from sqlalchemy.sql import Executable

_Processor = Callable[[Any], Any] | None


class _Compiled:
    """One statement compiled for one dialect and one set of parameter names."""

    __slots__ = ("fixed", "names", "positional", "processors", "sql")

    def __init__(self, stmt: Executable, dialect: Dialect, keys: Sequence[str]) -> None:
        compiled = stmt.compile(dialect=dialect, column_keys=list(keys))
        missing = [
            c.key
            for c in (*compiled.insert_prefetch, *compiled.update_prefetch)
            if c.key not in keys
        ]
        if missing:
            raise KeyError(f"pass values for {missing}: a prepared statement applies no defaults")
        if "POSTCOMPILE" in compiled.string:
            raise ValueError("expanding IN parameters are not supported by Prepared")
        self.sql = compiled.string
        self.positional = bool(compiled.positional)
        binds = compiled.binds
        self.names: tuple[str, ...] = (
            tuple(compiled.positiontup or ()) if self.positional else tuple(binds)
        )
        self.processors: tuple[_Processor, ...] = tuple(
            binds[name].type.dialect_impl(dialect).bind_processor(dialect) for name in self.names
        )
        # values written into the statement itself (``status == "active"``)
        self.fixed = {
            name: binds[name].effective_value
            for name in self.names
            if name not in keys and not binds[name].required
        }

    def bind(self, params: Mapping[str, Any]) -> tuple[Any, ...] | dict[str, Any]:
        values = []
        fixed = self.fixed
        for name, process in zip(self.names, self.processors, strict=True):
            if name in params:
                value = params[name]
            elif name in fixed:
                value = fixed[name]
            else:
                raise KeyError(f"no value given for the parameter {name!r}")
            values.append(value if process is None else process(value))
        return tuple(values) if self.positional else dict(zip(self.names, values, strict=True))


class Prepared:
    """A Core statement run on the DBAPI cursor of a SQLAlchemy ``Connection``.

    ``execute(conn, params)`` returns the driver's cursor (``fetchone``/``fetchall`` give
    plain tuples in the statement's column order).
    """

    def __init__(self, stmt: Executable) -> None:
        self.stmt = stmt
        self._by_dialect: dict[tuple[str, frozenset[str]], _Compiled] = {}

    def compiled(self, dialect: Dialect, keys: Sequence[str]) -> _Compiled:
        cache_key = (dialect.name, frozenset(keys))
        found = self._by_dialect.get(cache_key)
        if found is None:
            found = self._by_dialect[cache_key] = _Compiled(self.stmt, dialect, sorted(keys))
        return found

    def execute(self, conn: Connection, params: Mapping[str, Any]) -> Any:
        dialect = conn.dialect
        c = self.compiled(dialect, params.keys())
        bound = c.bind(params)
        cursor = conn.connection.dbapi_connection.cursor()  # type: ignore[union-attr]
        try:
            cursor.execute(c.sql, bound)
        except dialect.loaded_dbapi.Error as exc:
            cursor.close()
            raise DBAPIError.instance(
                c.sql, bound, exc, dialect.loaded_dbapi.Error, dialect=dialect
            ) from exc
        return cursor
