"""Account security in the service (issue 16, finding 5): failed logins limited, the same time
for an unknown user as for a wrong password, tokens that expire and rotate, users that can be
disabled and given a new password. Time moves through ``now=`` and the limiter's clock."""

from __future__ import annotations

import time
from datetime import timedelta

import pytest

from app.db.base import utcnow
from app.service import auth
from app.service.errors import Unauthorized


@pytest.fixture
def alice(db):
    with db.write() as s:
        auth.add_user(s, "alice", "operator", password="right password")
    return "alice"


def test_failed_logins_lock_the_user_and_the_address_out_for_a_while():
    now = [0.0]
    limiter = auth.LoginLimiter(max_failures=3, window_s=60.0, clock=lambda: now[0])
    for _ in range(3):
        limiter.check("alice", "10.0.0.1")
        limiter.failed("alice", "10.0.0.1")
    with pytest.raises(auth.TooManyAttempts) as info:
        limiter.check("alice", "10.0.0.2")  # the right password would be refused too
    assert info.value.status_code == 429 and 1 <= info.value.retry_after_s <= 60
    limiter.check("bob", "10.0.0.2")  # other users are not locked out
    now[0] = 61.0
    limiter.check("alice", "10.0.0.1")  # the window has passed
    # one address trying many names is limited too (4× the per-user limit)
    for i in range(12):
        limiter.failed(f"user{i}", "10.0.0.9")
    with pytest.raises(auth.TooManyAttempts):
        limiter.check("someone-new", "10.0.0.9")


def test_an_unknown_user_takes_as_long_as_a_wrong_password(db, alice):
    def timed(name: str) -> float:
        best = float("inf")
        for _ in range(3):
            with db.read() as s:
                t0 = time.perf_counter()
                with pytest.raises(Unauthorized, match="wrong username or password"):
                    auth.check_password(s, name, "wrong password")
                best = min(best, time.perf_counter() - t0)
        return best

    known, unknown = timed("alice"), timed("nobody")
    assert 0.5 < unknown / known < 2.0, (known, unknown)


def test_the_password_check_needs_no_write_transaction(db, alice):
    with db.read() as s:
        assert auth.check_password(s, "alice", "right password").username == "alice"
        assert not s.new and not s.dirty


def test_tokens_expire(db, alice):
    t0 = utcnow()
    with db.write() as s:
        token = auth.create_token(s, "alice", label="login", ttl_s=3600, now=t0)
    with db.read() as s:
        assert auth.authenticate(s, token, now=t0 + timedelta(seconds=3599)).username == "alice"
        with pytest.raises(Unauthorized, match="expired"):
            auth.authenticate(s, token, now=t0 + timedelta(seconds=3600))


def test_rotation_revokes_the_old_token_and_keeps_the_lifetime(db, alice):
    t0 = utcnow()
    with db.write() as s:
        old = auth.create_token(s, "alice", label="login", ttl_s=600, now=t0)
    with db.write() as s:
        new = auth.rotate_token(s, old)
    with db.read() as s:
        with pytest.raises(Unauthorized, match="revoked"):
            auth.authenticate(s, old)
        assert auth.authenticate(s, new).username == "alice"
        [_, info] = auth.list_tokens(s, "alice")
        assert (info.expires_at - info.created_at).total_seconds() == pytest.approx(600)


def test_disable_and_set_password(db, alice):
    with db.write() as s:
        token = auth.create_token(s, "alice", label="login")
        cli_token = auth.create_token(s, "alice", label="cli")
    with db.write() as s:
        auth.set_disabled(s, "alice", True)
    with db.read() as s:
        with pytest.raises(Unauthorized):
            auth.authenticate(s, cli_token)
        with pytest.raises(Unauthorized):
            auth.check_password(s, "alice", "right password")
    with db.write() as s:
        auth.set_disabled(s, "alice", False)
        assert auth.set_password(s, "alice", "a new password") == 1
    with db.read() as s:
        with pytest.raises(Unauthorized):
            auth.authenticate(s, token)  # login tokens end with the old password
        assert auth.authenticate(s, cli_token).username == "alice"
        auth.check_password(s, "alice", "a new password")
        with pytest.raises(Unauthorized):
            auth.check_password(s, "alice", "right password")
