"""Dependencies shared by the routes: settings, sessions, the caller and role checks."""

from __future__ import annotations

import time
from collections.abc import AsyncIterator, Awaitable, Callable, Sequence
from typing import Annotated, TypeVar

from fastapi import Depends, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import Response
from pydantic import BaseModel
from sqlalchemy.orm import Session

from app.config import Settings
from app.db.session import Database
from app.service import auth
from app.service.auth import OPERATOR, VIEWER, WORKER, Actor
from app.service.errors import Forbidden, Unauthorized
from app.service.runs import PreviewRunner

T = TypeVar("T")

# The dependencies are ``async def`` on purpose: FastAPI runs a sync dependency in a thread
# of its pool, and each such hop costs more than the work (a dict lookup, an indexed SELECT).
# Sync routes still run in the pool, so their queries never block the event loop; on the
# loop run only the token lookup and ``run_write``'s short writes while the writer is free.
#
# Writes open their session in the route body (``with db.write() as session:``), not
# through a yield dependency: a dependency's exit runs on the event loop, and a write
# transaction whose commit waits for the loop could hold SQLite's one write connection while
# ``run_write`` on the loop waits for it.


async def get_settings(request: Request) -> Settings:
    return request.app.state.settings


async def get_db(request: Request) -> Database:
    return request.app.state.db


async def get_previews(request: Request) -> PreviewRunner:
    return request.app.state.previews


async def read_session(db: Annotated[Database, Depends(get_db)]) -> AsyncIterator[Session]:
    """A read-only session (rolled back at the end)."""
    with db.read() as s:
        yield s


def _write(db: Database, work: Callable[[Session], T]) -> T:
    with db.write() as s:
        return work(s)


async def run_write(db: Database, work: Callable[[Session], T]) -> T:
    """``work(session)`` in a write transaction (committed on success), for routes whose whole
    job is one short write (a measurement post: ~1 ms of SQL and one commit, no file I/O).

    When SQLite's write connection is free, it runs right here on the event loop: the hop to a
    pool thread and back costs more than such a transaction (0.3-0.5 ms of a 2-3 ms post on
    the development VM). When another writer holds it, or on PostgreSQL, it runs in the
    threadpool, so the loop never waits for someone else's transaction. (A writer that takes
    the connection between the check and our first statement, or another program holding
    SQLite's lock, such as ``handful user add``, can still make the loop wait for one short
    transaction: write transactions here never run long work and always end in the thread
    that opened them.)
    """
    if db.writer_idle():
        return _write(db, work)
    return await run_in_threadpool(_write, db, work)


SettingsDep = Annotated[Settings, Depends(get_settings)]
DbDep = Annotated[Database, Depends(get_db)]
ReadSession = Annotated[Session, Depends(read_session)]
PreviewsDep = Annotated[PreviewRunner, Depends(get_previews)]

ANONYMOUS = Actor("anonymous", VIEWER)


def _bearer(request: Request) -> str | None:
    header = request.headers.get("authorization")
    if not header:
        # EventSource (SSE) cannot send headers: the events stream may carry ?token=
        if request.url.path.endswith("/events") and request.query_params.get("token"):
            return request.query_params["token"]
        return None
    scheme, _, token = header.partition(" ")
    if scheme.lower() != "bearer" or not token.strip():
        raise Unauthorized("the Authorization header must be 'Bearer <token>'")
    return token.strip()


TOKEN_CACHE_S = 5.0  # a revoked token or disabled user is refused at most this much later


def current_actor(request: Request) -> Actor | None:
    """The caller, or None when no token was sent (Unauthorized for a bad token).

    Valid tokens are remembered for ``TOKEN_CACHE_S`` (by their SHA-256) to spare a database
    round trip per request; unknown tokens are looked up every time.
    """
    token = _bearer(request)
    if token is None:
        return None
    cache: dict[str, tuple[Actor, float]] = request.app.state.token_cache
    digest = auth.token_digest(token)
    hit = cache.get(digest)
    now = time.monotonic()
    if hit is not None and hit[1] > now:
        return hit[0]
    db: Database = request.app.state.db
    with db.read() as s:
        actor = auth.authenticate(s, token)
    if len(cache) > 10_000:
        cache.clear()
    cache[digest] = (actor, now + TOKEN_CACHE_S)
    return actor


def require(*roles: str, what: str) -> Callable[..., Awaitable[Actor]]:
    """A dependency that lets only ``roles`` through: 401 without a token, 403 otherwise."""

    async def dependency(request: Request) -> Actor:
        actor = current_actor(request)
        if actor is None:
            raise Unauthorized(f"a token is required to {what} (Authorization: Bearer <token>)")
        if actor.role not in roles:
            raise Forbidden(f"role {actor.role!r} may not {what}; needs {' or '.join(roles)}")
        return actor

    return dependency


async def reader(request: Request) -> Actor:
    """Reads: operators and viewers (anyone when settings.public_read); never worker tokens."""
    actor = current_actor(request)
    if actor is None:
        if request.app.state.settings.public_read:
            return ANONYMOUS
        raise Unauthorized("a token is required to read (Authorization: Bearer <token>)")
    if actor.role not in (OPERATOR, VIEWER):
        raise Forbidden(f"role {actor.role!r} may only claim, heartbeat and report results")
    return actor


async def any_user(request: Request) -> Actor:
    actor = current_actor(request)
    if actor is None:
        raise Unauthorized("a token is required (Authorization: Bearer <token>)")
    return actor


Reader = Annotated[Actor, Depends(reader)]
AnyUser = Annotated[Actor, Depends(any_user)]
Operator = Annotated[Actor, Depends(require(OPERATOR, what="change anything"))]
WorkerOrOperator = Annotated[
    Actor, Depends(require(WORKER, OPERATOR, what="claim, heartbeat or report trials"))
]


def json_response(model: BaseModel | Sequence[BaseModel], status_code: int = 200) -> Response:
    """Serialise a reply once with pydantic (FastAPI would validate and encode it again);
    routes using this declare ``response_model`` for the OpenAPI schema."""
    if isinstance(model, BaseModel):
        body = model.model_dump_json().encode()
    else:
        body = b"[" + b",".join(m.model_dump_json().encode() for m in model) + b"]"
    return Response(body, status_code=status_code, media_type="application/json")
