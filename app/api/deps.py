"""Dependencies shared by the routes: settings, sessions, the caller and role checks."""

from __future__ import annotations

from collections.abc import AsyncIterator, Awaitable, Callable, Sequence
from typing import Annotated

from fastapi import Depends, Path, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import Response
from pydantic import BaseModel
from sqlalchemy.orm import Session

from app.config import Settings
from app.db.session import Database
from app.service import auth
from app.service.auth import OPERATOR, VIEWER, WORKER, Actor
from app.service.compute import ComputeRunner
from app.service.errors import Forbidden, Unauthorized
from app.service.runs import PreviewRunner

# No request waits for the database on the event loop: routes that touch it are sync (run in
# the threadpool), and the token lookup behind ``current_actor`` runs there too (on a cache
# miss). Write routes open their session in the route body (``with db.write() as session:``),
# so every write transaction begins, commits and ends in the thread that did the work.


async def get_settings(request: Request) -> Settings:
    return request.app.state.settings


async def get_db(request: Request) -> Database:
    return request.app.state.db


async def get_previews(request: Request) -> PreviewRunner:
    return request.app.state.previews


async def get_compute(request: Request) -> ComputeRunner:
    return request.app.state.compute


async def read_session(db: Annotated[Database, Depends(get_db)]) -> AsyncIterator[Session]:
    """A read-only session (rolled back at the end)."""
    with db.read() as s:
        yield s


MAX_ID = 2**63 - 1  # the largest id a database row can have (SQLite, PostgreSQL BIGINT)
ExperimentId = Annotated[int, Path(ge=1, le=MAX_ID, description="an experiment's id")]
TrialId = Annotated[int, Path(ge=1, le=MAX_ID, description="a trial's id")]
MeasurementId = Annotated[int, Path(ge=1, le=MAX_ID, description="a measurement's id")]

SettingsDep = Annotated[Settings, Depends(get_settings)]
DbDep = Annotated[Database, Depends(get_db)]
ReadSession = Annotated[Session, Depends(read_session)]
PreviewsDep = Annotated[PreviewRunner, Depends(get_previews)]
ComputeDep = Annotated[ComputeRunner, Depends(get_compute)]

ANONYMOUS = Actor("anonymous", VIEWER)


def bearer_token(request: Request) -> str | None:
    header = request.headers.get("authorization")
    if not header:  # tokens travel only in this header: never in a URL (access logs)
        return None
    scheme, _, token = header.partition(" ")
    if scheme.lower() != "bearer" or not token.strip():
        raise Unauthorized("the Authorization header must be 'Bearer <token>'")
    return token.strip()


def _lookup(db: Database, token: str) -> Actor:
    with db.read() as s:
        return auth.authenticate(s, token)


async def current_actor(request: Request) -> Actor | None:
    """The caller, or None when no token was sent (Unauthorized for a bad token).

    Looked up on every request (one indexed SELECT, in the threadpool): a revoked or expired
    token, or a disabled user, is refused from the next request on.
    """
    token = bearer_token(request)
    if token is None:
        return None
    return await run_in_threadpool(_lookup, request.app.state.db, token)


def require(*roles: str, what: str) -> Callable[..., Awaitable[Actor]]:
    """A dependency that lets only ``roles`` through: 401 without a token, 403 otherwise."""

    async def dependency(request: Request) -> Actor:
        actor = await current_actor(request)
        if actor is None:
            raise Unauthorized(f"a token is required to {what} (Authorization: Bearer <token>)")
        if actor.role not in roles:
            raise Forbidden(f"role {actor.role!r} may not {what}; needs {' or '.join(roles)}")
        return actor

    return dependency


async def reader(request: Request) -> Actor:
    """Reads: operators and viewers (anyone when settings.public_read); never worker tokens."""
    actor = await current_actor(request)
    if actor is None:
        if request.app.state.settings.public_read:
            return ANONYMOUS
        raise Unauthorized("a token is required to read (Authorization: Bearer <token>)")
    if actor.role not in (OPERATOR, VIEWER):
        raise Forbidden(f"role {actor.role!r} may only claim, heartbeat and report results")
    return actor


async def any_user(request: Request) -> Actor:
    actor = await current_actor(request)
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
