"""Login and who-am-I."""

from __future__ import annotations

from fastapi import APIRouter, Request

from app.api.deps import AnyUser, DbDep, SettingsDep, bearer_token
from app.service import auth
from app.service.errors import Unauthorized
from app.service.schemas import LoginIn, LoginRead, UserRead

router = APIRouter(tags=["auth"])


@router.post("/auth/login")
def login(body: LoginIn, db: DbDep, settings: SettingsDep, request: Request) -> LoginRead:
    """Exchange a username and password for a new API token (valid HANDFUL_TOKEN_TTL_S).

    Failed logins are limited per user and per address (429 with Retry-After). The password
    is checked in a read transaction; only a right one opens a (short) write to store the
    token."""
    limiter: auth.LoginLimiter = request.app.state.login_limiter
    address = request.client.host if request.client else "?"
    limiter.check(body.username, address)
    with db.read() as session:
        try:
            user = auth.check_password(session, body.username, body.password)
        except Unauthorized:
            limiter.failed(body.username, address)
            raise
        role = user.role
    limiter.succeeded(body.username)
    with db.write() as session:
        token = auth.create_token(
            session,
            body.username,
            label="login",
            actor=auth.Actor(body.username, role),
            ttl_s=settings.token_ttl_s,
        )
    return LoginRead(token=token, user=UserRead(username=body.username, role=role))


@router.post("/auth/rotate")
def rotate(db: DbDep, actor: AnyUser, request: Request) -> LoginRead:
    """A new token for the caller (same label and lifetime); the one sent is revoked now."""
    token = bearer_token(request)
    assert token is not None  # AnyUser let it through
    with db.write() as session:
        new = auth.rotate_token(session, token)
    return LoginRead(token=new, user=UserRead(username=actor.username, role=actor.role))


@router.get("/me")
def me(actor: AnyUser) -> UserRead:
    """The user this token belongs to."""
    return UserRead(username=actor.username, role=actor.role)
