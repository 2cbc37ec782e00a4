"""Smaller findings of issue 16 (finding 8): names without NUL or bidi controls, strict JSON
in the audit log, a database file only its owner can read, security headers."""

from __future__ import annotations

import json
import os
import sqlite3

import httpx
import pytest


def _post(server, path, body):
    headers = {"Authorization": f"Bearer {server.tokens['operator']}"}
    return httpx.post(server.url + path, json=body, headers=headers, timeout=30)


@pytest.mark.parametrize(
    ("field", "value"),
    [("name", "ok\x00name"), ("name", "invoice\u202etxt.exe"), ("notes", "a\x00b")],
)
def test_nul_and_bidi_characters_are_refused(live_server, field, value):
    body = {"name": "n", "task": "tip_speed", "levels": 3, "method": "random", field: value}
    r = _post(live_server, "/api/experiments", body)
    assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["body", field]


def test_ordinary_text_still_passes(live_server):
    body = {
        "name": "Wurf – 2. Versuch",
        "task": "tip_speed",
        "levels": 3,
        "method": "random",
        "notes": "line one\nline two\tand a tab; שלום",
    }
    assert _post(live_server, "/api/experiments", body).status_code == 201


def test_the_audit_log_holds_strict_json(module_server):
    op = module_server.client("operator")
    worker = module_server.client("worker")
    exp = op.create_experiment(name="nan", task="tip_speed", levels=3, method="random")
    [t] = op.suggest(exp["id"])
    [c] = worker.claim("w", "sim")
    r = httpx.post(  # Python's json reads NaN: a worker's summary may carry one
        f"{module_server.url}/api/trials/{t['id']}/result",
        content=b'{"lease_id": "%s", "objective": 1.5, "summary": {"x": NaN, "y": Infinity}}'
        % c["lease_id"].encode(),
        headers={
            "Authorization": f"Bearer {module_server.tokens['worker']}",
            "Content-Type": "application/json",
        },
        timeout=30,
    )
    assert r.status_code == 200, r.text
    conn = sqlite3.connect(module_server.data_dir / "handful.db")
    rows = [d for (d,) in conn.execute("SELECT detail FROM audit_log WHERE detail IS NOT NULL")]
    conn.close()
    for text in rows:
        json.loads(text, parse_constant=lambda c: pytest.fail(f"{c} in the audit log"))
    assert any('"x": null' in text for text in rows)


def test_the_database_file_is_private(live_server):
    for name in ("handful.db", "handful.db-wal"):
        path = live_server.data_dir / name
        if path.exists():
            assert oct(os.stat(path).st_mode & 0o777) == "0o600", name


def test_replies_carry_security_headers(live_server):
    r = httpx.get(live_server.url + "/health")
    assert r.headers["X-Frame-Options"] == "DENY"
    assert "frame-ancestors 'none'" in r.headers["Content-Security-Policy"]
    assert r.headers["X-Content-Type-Options"] == "nosniff"
