"""Users, passwords (scrypt), API tokens (random, stored as SHA-256) and roles."""

from __future__ import annotations

import hashlib
import hmac
import re
import secrets
from dataclasses import dataclass
from typing import Final

from sqlalchemy import select
from sqlalchemy.orm import Session

from app.db.base import utcnow
from app.db.models import Token, User
from app.service.audit import record
from app.service.errors import Conflict, InvalidInput, NotFound, Unauthorized

OPERATOR, VIEWER, WORKER = "operator", "viewer", "worker"
ROLES: Final = (OPERATOR, VIEWER, WORKER)
_USERNAME = re.compile(r"^[A-Za-z0-9_.@-]{1,64}$")
_SCRYPT = {"n": 2**14, "r": 8, "p": 1}


@dataclass(frozen=True)
class Actor:
    """Who is making a request."""

    username: str
    role: str


SYSTEM = Actor("system", OPERATOR)


def hash_password(password: str) -> str:
    """scrypt hash as ``scrypt$n$r$p$salt_hex$hash_hex``."""
    salt = secrets.token_bytes(16)
    digest = hashlib.scrypt(password.encode(), salt=salt, dklen=32, **_SCRYPT)
    return f"scrypt${_SCRYPT['n']}${_SCRYPT['r']}${_SCRYPT['p']}${salt.hex()}${digest.hex()}"


def verify_password(password: str, stored: str) -> bool:
    """Constant-time check of ``password`` against a ``hash_password`` string."""
    try:
        scheme, n, r, p, salt_hex, hash_hex = stored.split("$")
    except ValueError:
        return False
    if scheme != "scrypt":
        return False
    digest = hashlib.scrypt(
        password.encode(), salt=bytes.fromhex(salt_hex), dklen=32, n=int(n), r=int(r), p=int(p)
    )
    return hmac.compare_digest(digest.hex(), hash_hex)


def token_digest(token: str) -> str:
    """SHA-256 hex of a token: what the database keeps."""
    return hashlib.sha256(token.encode()).hexdigest()


def add_user(
    session: Session,
    username: str,
    role: str,
    *,
    password: str | None = None,
    actor: Actor = SYSTEM,
) -> User:
    """Create a user (flushed; the caller's ``Database.write`` commits).

    Raises InvalidInput for a bad name/role, Conflict if taken."""
    if not _USERNAME.match(username):
        raise InvalidInput(f"username {username!r}: use 1-64 letters, digits or _ . @ -")
    if role not in ROLES:
        raise InvalidInput(f"role {role!r} is not one of {', '.join(ROLES)}")
    if password is not None and len(password) < 8:
        raise InvalidInput("password must have at least 8 characters")
    if session.scalar(select(User).where(User.username == username)) is not None:
        raise Conflict(f"user {username!r} already exists")
    user = User(
        username=username,
        role=role,
        password_hash=hash_password(password) if password is not None else None,
    )
    session.add(user)
    session.flush()
    record(
        session,
        actor=actor.username,
        action="user.add",
        entity="user",
        entity_id=user.id,
        after=role,
        detail={"username": username},
    )
    session.flush()
    return user


def create_token(session: Session, username: str, *, label: str = "", actor: Actor = SYSTEM) -> str:
    """Issue a new random token for ``username``; returns the plain token once (flushed;
    ``Database.write`` commits)."""
    user = session.scalar(select(User).where(User.username == username))
    if user is None:
        raise NotFound(f"no user named {username!r}")
    token = "hf_" + secrets.token_urlsafe(32)
    session.add(Token(user_id=user.id, token_sha256=token_digest(token), label=label[:64]))
    record(
        session,
        actor=actor.username,
        action="token.create",
        entity="user",
        entity_id=user.id,
        detail={"username": username, "label": label[:64]},
    )
    session.flush()
    return token


def login(session: Session, username: str, password: str) -> tuple[str, User]:
    """Check a password and issue a token. Raises Unauthorized with one message for any failure."""
    user = session.scalar(select(User).where(User.username == username))
    ok = (
        user is not None
        and not user.disabled
        and user.password_hash is not None
        and verify_password(password, user.password_hash)
    )
    if not ok or user is None:
        raise Unauthorized("wrong username or password")
    return create_token(
        session, username, label="login", actor=Actor(user.username, user.role)
    ), user


def authenticate(session: Session, token: str) -> Actor:
    """The Actor a bearer token belongs to. Raises Unauthorized for an unknown/revoked token."""
    row = session.execute(
        select(User.username, User.role, User.disabled, Token.revoked_at)
        .join(User, Token.user_id == User.id)
        .where(Token.token_sha256 == token_digest(token))
    ).first()
    if row is None:
        raise Unauthorized("invalid token")
    username, role, disabled, revoked_at = row
    if revoked_at is not None or disabled:
        raise Unauthorized("token revoked or user disabled")
    return Actor(username, role)


def revoke_tokens(session: Session, username: str, *, actor: Actor = SYSTEM) -> int:
    """Revoke every token of ``username``; returns how many (flushed; ``Database.write``
    commits)."""
    user = session.scalar(select(User).where(User.username == username))
    if user is None:
        raise NotFound(f"no user named {username!r}")
    now = utcnow()
    n = 0
    for tok in user.tokens:
        if tok.revoked_at is None:
            tok.revoked_at = now
            n += 1
    record(
        session,
        actor=actor.username,
        action="token.revoke",
        entity="user",
        entity_id=user.id,
        detail={"username": username, "count": n},
    )
    session.flush()
    return n
