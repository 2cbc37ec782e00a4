"""Accounts over HTTP and the CLI (issue 16, finding 5): login limited (429 + Retry-After),
login tokens that expire and rotate, ``handful user``/``handful token`` with immediate effect,
a wrong password answered without waiting for the write lock, worker tokens out of ps."""

from __future__ import annotations

import sqlite3
import time

import httpx
from typer.testing import CliRunner

from app.cli import app as cli

from ..conftest import PASSWORD

SERVER_ENV = {"HANDFUL_LOGIN_MAX_FAILURES": "3", "HANDFUL_TOKEN_TTL_S": "3"}


def _login(server, username, password):
    return httpx.post(
        f"{server.url}/api/auth/login",
        json={"username": username, "password": password},
        timeout=30,
    )


def test_wrong_passwords_are_limited_then_even_the_right_one_waits(module_server):
    for _ in range(3):
        assert _login(module_server, "viewer", "wrong password").status_code == 401
    r = _login(module_server, "viewer", PASSWORD)
    assert r.status_code == 429 and r.json()["code"] == "too_many_attempts"
    assert int(r.headers["Retry-After"]) > 0
    assert _login(module_server, "operator", PASSWORD).status_code == 200  # only that user


def test_login_tokens_expire_and_rotate(module_server):
    r = _login(module_server, "worker", PASSWORD)
    token = r.json()["token"]
    me = f"{module_server.url}/api/me"
    assert httpx.get(me, headers={"Authorization": f"Bearer {token}"}).status_code == 200
    r = httpx.post(
        f"{module_server.url}/api/auth/rotate",
        headers={"Authorization": f"Bearer {token}"},
    )
    assert r.status_code == 200
    new = r.json()["token"]
    assert httpx.get(me, headers={"Authorization": f"Bearer {token}"}).status_code == 401
    assert httpx.get(me, headers={"Authorization": f"Bearer {new}"}).status_code == 200
    time.sleep(3.2)  # the server's HANDFUL_TOKEN_TTL_S
    r = httpx.get(me, headers={"Authorization": f"Bearer {new}"})
    assert r.status_code == 401 and "expired" in r.json()["detail"]


def test_cli_disable_revoke_and_list_take_effect_at_once(module_server):
    runner = CliRunner()
    data = ["--data-dir", str(module_server.data_dir)]
    r = runner.invoke(cli, ["user", "add", "dora", "--role", "viewer", *data])
    assert r.exit_code == 0, r.output
    r = runner.invoke(cli, ["token", "create", "dora", "--label", "laptop", *data])
    token = r.output.strip().splitlines()[-1]
    headers = {"Authorization": f"Bearer {token}"}
    me = f"{module_server.url}/api/me"
    assert httpx.get(me, headers=headers).status_code == 200
    r = runner.invoke(cli, ["user", "disable", "dora", *data])
    assert r.exit_code == 0, r.output
    assert httpx.get(me, headers=headers).status_code == 401  # the very next request
    r = runner.invoke(cli, ["user", "enable", "dora", *data])
    assert httpx.get(me, headers=headers).status_code == 200
    r = runner.invoke(cli, ["user", "list", *data])
    assert "dora\tviewer\tactive\ttoken only" in r.output
    r = runner.invoke(cli, ["token", "list", "--user", "dora", *data])
    [line] = r.output.strip().splitlines()
    assert "\tdora\tlaptop\t" in line and line.endswith("active") and token not in line
    token_id = line.split("\t")[0]
    r = runner.invoke(cli, ["token", "revoke", token_id, *data])
    assert r.exit_code == 0 and "revoked" in r.output
    assert httpx.get(me, headers=headers).status_code == 401
    r = runner.invoke(
        cli, ["user", "set-password", "dora", *data], input="new password 1\nnew password 1\n"
    )
    assert r.exit_code == 0, r.output
    assert _login(module_server, "dora", "new password 1").status_code == 200


def test_a_wrong_password_does_not_wait_for_the_write_lock(module_server):
    lock = sqlite3.connect(module_server.data_dir / "handful.db", isolation_level=None)
    lock.execute("BEGIN IMMEDIATE")  # another program holds the write lock
    try:
        t0 = time.perf_counter()
        r = _login(module_server, "nobody", "wrong password")
        elapsed = time.perf_counter() - t0
    finally:
        lock.rollback()
        lock.close()
    assert r.status_code == 401 and elapsed < 2


def test_the_worker_reads_its_token_from_a_file_or_the_environment(tmp_path, monkeypatch):
    import typer

    from app.cli.worker import resolve_token

    path = tmp_path / "token"
    path.write_text("hf_from_file\n")
    monkeypatch.setenv("HANDFUL_TOKEN", "hf_from_env")
    assert resolve_token(None, path) == "hf_from_file"
    assert resolve_token(None, None) == "hf_from_env"
    monkeypatch.delenv("HANDFUL_TOKEN")
    assert resolve_token("hf_cli", None) == "hf_cli"
    try:
        resolve_token(None, None)
    except typer.BadParameter as exc:
        assert "--token-file" in str(exc)
    else:
        raise AssertionError("no token must be an error")
