"""Users, passwords (scrypt), API tokens (random, stored as SHA-256) and roles."""

from __future__ import annotations

import hashlib
import hmac
import math
import re
import secrets
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from datetime import datetime, timedelta
from typing import Final

from sqlalchemy import select
from sqlalchemy.orm import Session

from app.db.base import utcnow
from app.db.models import Token, User
from app.service.audit import record
from app.service.errors import Conflict, InvalidInput, NotFound, ServiceError, Unauthorized

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


def create_token(
    session: Session,
    username: str,
    *,
    label: str = "",
    actor: Actor = SYSTEM,
    ttl_s: float | None = None,
    now: datetime | None = None,
) -> str:
    """Issue a new random token for ``username``, valid ``ttl_s`` seconds (None: until
    revoked); returns the plain token once (flushed; ``Database.write`` commits)."""
    user = session.scalar(select(User).where(User.username == username))
    if user is None:
        raise NotFound(f"no user named {username!r}")
    if user.disabled:
        raise Conflict(f"user {username!r} is disabled")
    now = now or utcnow()
    token = "hf_" + secrets.token_urlsafe(32)
    session.add(
        Token(
            user_id=user.id,
            token_sha256=token_digest(token),
            label=label[:64],
            created_at=now,
            expires_at=None if ttl_s is None else now + timedelta(seconds=ttl_s),
        )
    )
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


# A hash of a password nobody has: checked when the user does not exist (or cannot log in),
# so that an unknown username takes as long as a wrong password.
_DUMMY_HASH = hash_password(secrets.token_hex(16))


def check_password(session: Session, username: str, password: str) -> User:
    """The user whose password this is (read only: no write transaction). One message, and
    about one scrypt's time, for every failure: unknown user, disabled, no password, wrong."""
    user = session.scalar(select(User).where(User.username == username))
    usable = user is not None and not user.disabled and user.password_hash is not None
    stored = user.password_hash if usable and user is not None else _DUMMY_HASH
    ok = verify_password(password, stored or _DUMMY_HASH)
    if not (ok and usable) or user is None:
        raise Unauthorized("wrong username or password")
    return user


def login(
    session: Session, username: str, password: str, *, ttl_s: float | None = None
) -> tuple[str, User]:
    """Check a password and issue a token (both in ``session``; the server checks first in a
    read session, then writes, see ``app.api.routes.auth``). Unauthorized for any failure."""
    user = check_password(session, username, password)
    token = create_token(
        session, username, label="login", actor=Actor(user.username, user.role), ttl_s=ttl_s
    )
    return token, user


class TooManyAttempts(ServiceError):
    """Too many failed logins for this user or from this address (429, Retry-After)."""

    status_code = 429
    code = "too_many_attempts"

    def __init__(self, message: str, *, retry_after_s: int) -> None:
        super().__init__(message)
        self.retry_after_s = retry_after_s


class LoginLimiter:
    """Failed logins per username and per client address in a sliding window: past
    ``max_failures`` (per user; 4× that per address) every attempt is refused, the right
    password too, until the oldest failure leaves the window. In memory, per process."""

    def __init__(
        self,
        max_failures: int = 5,
        window_s: float = 900.0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.max_failures = max_failures
        self.window_s = window_s
        self.clock = clock
        self._failures: dict[str, deque[float]] = {}
        self._lock = threading.Lock()

    def _recent(self, key: str, now: float) -> deque[float]:
        q = self._failures.setdefault(key, deque())
        while q and q[0] <= now - self.window_s:
            q.popleft()
        return q

    def check(self, username: str, address: str) -> None:
        """TooManyAttempts if this user or address is locked out now."""
        now = self.clock()
        with self._lock:
            for key, limit in (
                (f"u:{username}", self.max_failures),
                (f"a:{address}", 4 * self.max_failures),
            ):
                q = self._recent(key, now)
                if len(q) >= limit:
                    wait = max(1, math.ceil(q[0] + self.window_s - now))
                    raise TooManyAttempts(
                        f"too many failed logins; try again in {wait} s", retry_after_s=wait
                    )

    def failed(self, username: str, address: str) -> None:
        now = self.clock()
        with self._lock:
            if len(self._failures) > 100_000:  # a flood of made-up names: forget the oldest
                self._failures.clear()
            for key in (f"u:{username}", f"a:{address}"):
                self._recent(key, now).append(now)

    def succeeded(self, username: str) -> None:
        with self._lock:
            self._failures.pop(f"u:{username}", None)


def authenticate(session: Session, token: str, *, now: datetime | None = None) -> Actor:
    """The Actor a bearer token belongs to. Unauthorized for an unknown, revoked or expired
    token, or a disabled user."""
    row = session.execute(
        select(User.username, User.role, User.disabled, Token.revoked_at, Token.expires_at)
        .join(User, Token.user_id == User.id)
        .where(Token.token_sha256 == token_digest(token))
    ).first()
    if row is None:
        raise Unauthorized("invalid token")
    username, role, disabled, revoked_at, expires_at = row
    if revoked_at is not None or disabled:
        raise Unauthorized("token revoked or user disabled")
    if expires_at is not None and expires_at <= (now or utcnow()):
        raise Unauthorized("token expired: log in again")
    return Actor(username, role)


def rotate_token(
    session: Session, token: str, *, ttl_s: float | None = None, now: datetime | None = None
) -> str:
    """A new token for the same user and label, valid ``ttl_s`` (None: as long as the old one
    was meant to be); the old one is revoked at once."""
    now = now or utcnow()
    old = session.scalar(select(Token).where(Token.token_sha256 == token_digest(token)))
    if old is None or old.revoked_at is not None:
        raise Unauthorized("invalid token")
    if ttl_s is None and old.expires_at is not None:
        ttl_s = (old.expires_at - old.created_at).total_seconds()
    user = old.user
    new = create_token(
        session,
        user.username,
        label=old.label,
        actor=Actor(user.username, user.role),
        ttl_s=ttl_s,
        now=now,
    )
    old.revoked_at = now
    record(
        session,
        actor=user.username,
        action="token.rotate",
        entity="user",
        entity_id=user.id,
        detail={"username": user.username, "token_id": old.id},
    )
    session.flush()
    return new


@dataclass(frozen=True)
class TokenInfo:
    id: int
    username: str
    label: str
    created_at: datetime
    expires_at: datetime | None
    revoked_at: datetime | None


def list_tokens(session: Session, username: str | None = None) -> list[TokenInfo]:
    """Every token (or ``username``'s), oldest first; never the secret, which is not kept."""
    q = select(Token, User.username).join(User, Token.user_id == User.id).order_by(Token.id)
    if username is not None:
        q = q.where(User.username == username)
    return [
        TokenInfo(t.id, name, t.label, t.created_at, t.expires_at, t.revoked_at)
        for t, name in session.execute(q)
    ]


def revoke_token(session: Session, token_id: int, *, actor: Actor = SYSTEM) -> bool:
    """Revoke one token by id; False if it was revoked already. NotFound if there is none."""
    tok = session.get(Token, token_id)
    if tok is None:
        raise NotFound(f"no token with id {token_id}")
    if tok.revoked_at is not None:
        return False
    tok.revoked_at = utcnow()
    record(
        session,
        actor=actor.username,
        action="token.revoke",
        entity="user",
        entity_id=tok.user_id,
        detail={"token_id": token_id, "count": 1},
    )
    session.flush()
    return True


def _user(session: Session, username: str) -> User:
    user = session.scalar(select(User).where(User.username == username))
    if user is None:
        raise NotFound(f"no user named {username!r}")
    return user


def list_users(session: Session) -> list[User]:
    return list(session.scalars(select(User).order_by(User.username)))


def set_disabled(session: Session, username: str, disabled: bool, *, actor: Actor = SYSTEM) -> None:
    """Disable (every token refused at once, no login) or enable a user."""
    user = _user(session, username)
    user.disabled = disabled
    record(
        session,
        actor=actor.username,
        action="user.disable" if disabled else "user.enable",
        entity="user",
        entity_id=user.id,
        detail={"username": username},
    )
    session.flush()


def set_password(session: Session, username: str, password: str, *, actor: Actor = SYSTEM) -> int:
    """Set a user's password; their login tokens are revoked (returns how many)."""
    if len(password) < 8:
        raise InvalidInput("password must have at least 8 characters")
    user = _user(session, username)
    user.password_hash = hash_password(password)
    now = utcnow()
    n = 0
    for tok in user.tokens:
        if tok.revoked_at is None and tok.label == "login":
            tok.revoked_at = now
            n += 1
    record(
        session,
        actor=actor.username,
        action="user.set_password",
        entity="user",
        entity_id=user.id,
        detail={"username": username, "login_tokens_revoked": n},
    )
    session.flush()
    return n


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
