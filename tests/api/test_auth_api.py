"""Auth per role: no token on a write → 401, viewer write → 403, worker only claims/heartbeats/
reports; login, /api/me; tokens and passwords stored hashed."""

from __future__ import annotations

import sqlite3

import httpx
import pytest

from app.client import HandfulAPIError, HandfulClient
from app.service.auth import token_digest

WORKER_ROUTES = {
    "/api/workers/claim",
    "/api/leases/{lease_id}/heartbeat",
    "/api/trials/{trial_id}/result",
}
OPEN_ROUTES = {"/api/auth/login", "/api/auth/rotate"}  # any user; test_accounts_api


def _routes(live_server, methods):
    spec = httpx.get(live_server.url + "/openapi.json").json()
    out = []
    for path, ops in spec["paths"].items():
        if not path.startswith("/api") or path in OPEN_ROUTES:
            continue
        for method in ops:
            if method.upper() in methods:
                out.append((method.upper(), path))
    return out


def _call(live_server, method, path, role):
    url = live_server.url + path.replace("{experiment_id}", "1").replace("{trial_id}", "1").replace(
        "{lease_id}", "x"
    ).replace("{job_id}", "x")
    headers = {"Authorization": f"Bearer {live_server.tokens[role]}"} if role else {}
    return httpx.request(method, url, json={}, headers=headers, timeout=30)


def test_every_write_needs_a_token_and_the_right_role(live_server):
    writes = _routes(live_server, {"POST", "PATCH", "PUT", "DELETE"})
    assert len(writes) >= 15
    for method, path in writes:
        r = _call(live_server, method, path, None)
        assert r.status_code == 401, (method, path, r.text)
        assert "token is required" in r.json()["detail"]
        r = _call(live_server, method, path, "viewer")
        assert r.status_code == 403, (method, path, r.text)
        r = _call(live_server, method, path, "worker")
        if path in WORKER_ROUTES:
            assert r.status_code not in (401, 403), (method, path, r.text)
        else:
            assert r.status_code == 403, (method, path, r.text)
            assert "worker" in r.json()["detail"]


def test_reads_need_an_operator_or_viewer_token(live_server):
    reads = _routes(live_server, {"GET"})
    assert len(reads) >= 10
    for method, path in reads:
        if path == "/api/me":
            continue
        assert _call(live_server, method, path, None).status_code == 401, path
        assert _call(live_server, method, path, "worker").status_code == 403, path
        for role in ("viewer", "operator"):
            assert _call(live_server, method, path, role).status_code not in (401, 403), path


def test_operator_writes_and_viewer_reads(live_server, api, viewer_api):
    exp = api.create_experiment(name="x", task="tip_speed", levels=3, method="random")
    assert viewer_api.get_experiment(exp["id"])["id"] == exp["id"]
    with pytest.raises(HandfulAPIError) as info:
        viewer_api.suggest(exp["id"])
    assert info.value.status == 403 and "viewer" in info.value.detail


def test_worker_token_cannot_confirm_create_or_measure(api, worker_api, new_exp):
    exp = new_exp(api, name="hw", target="hardware")
    [trial] = api.suggest(exp["id"])
    attempts = [
        lambda: worker_api.confirm_trial(trial["id"], trial["schedule_hash"]),
        lambda: worker_api.create_experiment(name="x", task="tip_speed", levels=3),
        lambda: worker_api.add_measurements(trial["id"], [{"value": 1.0, "unit": "m/s"}]),
        lambda: worker_api.attach_trial(exp["id"], [0.5] * 10),
        lambda: worker_api.suggest(exp["id"]),
        lambda: worker_api.resolve_trial(trial["id"], "fail", "x"),
        lambda: worker_api.get_trial(trial["id"]),
    ]
    for attempt in attempts:
        with pytest.raises(HandfulAPIError) as info:
            attempt()
        assert info.value.status == 403
    assert api.get_trial(trial["id"])["status"] == "awaiting_confirmation"


def test_me_and_login(live_server):
    for role in ("operator", "viewer", "worker"):
        assert live_server.client(role).me() == {"username": role, "role": role}
    c = HandfulClient(live_server.url)
    try:
        out = c.login("viewer", "correct horse battery")
        assert out["user"] == {"username": "viewer", "role": "viewer"}
        assert out["token"].startswith("hf_") and c.me()["role"] == "viewer"
        for user, pw in (("viewer", "wrong password"), ("nobody", "whatever1")):
            with pytest.raises(HandfulAPIError) as info:
                c.login(user, pw)
            assert info.value.status == 401
            assert info.value.detail == "wrong username or password"
    finally:
        c.close()


def test_bad_tokens_are_401(live_server):
    for header in ("Bearer hf_not_a_token", "Basic abc", "Bearer"):
        r = httpx.get(live_server.url + "/api/me", headers={"Authorization": header})
        assert r.status_code == 401, header
    assert httpx.get(live_server.url + "/health").json()["status"] == "ok"


def test_tokens_and_passwords_are_stored_hashed(live_server):
    con = sqlite3.connect(live_server.db_url.removeprefix("sqlite:///"))
    try:
        digests = {row[0] for row in con.execute("SELECT token_sha256 FROM tokens")}
        hashes = [row[0] for row in con.execute("SELECT password_hash FROM users")]
    finally:
        con.close()
    for token in live_server.tokens.values():
        assert token not in digests and token_digest(token) in digests
    assert all(h.startswith("scrypt$") and "correct horse" not in h for h in hashes)
