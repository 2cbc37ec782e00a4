"""Login and who-am-I."""

from __future__ import annotations

from fastapi import APIRouter

from app.api.deps import AnyUser, DbDep
from app.service import auth
from app.service.schemas import LoginIn, LoginRead, UserRead

router = APIRouter(tags=["auth"])


@router.post("/auth/login")
def login(body: LoginIn, db: DbDep) -> LoginRead:
    """Exchange a username and password for a new API token."""
    with db.write() as session:
        token, user = auth.login(session, body.username, body.password)
        return LoginRead(token=token, user=UserRead(username=user.username, role=user.role))


@router.get("/me")
def me(actor: AnyUser) -> UserRead:
    """The user this token belongs to."""
    return UserRead(username=actor.username, role=actor.role)
