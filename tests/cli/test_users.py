"""`handful user add` and `handful token create` against a real data folder."""

from __future__ import annotations

from typer.testing import CliRunner

from app.cli import app as cli
from app.db.session import Database
from app.service.auth import authenticate, login


def test_user_add_and_token_create(tmp_path):
    runner = CliRunner()
    data = str(tmp_path / "data")
    r = runner.invoke(cli, ["user", "add", "alice", "--role", "operator", "--data-dir", data])
    assert r.exit_code == 0, r.output
    assert "alice (operator) added" in r.output
    r = runner.invoke(cli, ["user", "add", "alice", "--role", "viewer", "--data-dir", data])
    assert r.exit_code == 1 and "already exists" in r.output
    r = runner.invoke(cli, ["user", "add", "bob", "--role", "boss", "--data-dir", data])
    assert r.exit_code == 1 and "not one of operator, viewer, worker" in r.output
    r = runner.invoke(cli, ["token", "create", "nobody", "--data-dir", data])
    assert r.exit_code == 1 and "no user named 'nobody'" in r.output
    r = runner.invoke(
        cli,
        ["user", "add", "carol", "--role", "viewer", "--password", "--data-dir", data],
        input="s3cret-pass\ns3cret-pass\n",
    )
    assert r.exit_code == 0, r.output
    r = runner.invoke(cli, ["token", "create", "alice", "--data-dir", data])
    assert r.exit_code == 0, r.output
    token = r.output.strip().splitlines()[-1]
    db = Database(f"sqlite:///{tmp_path / 'data' / 'handful.db'}")
    try:
        with db.read() as s:
            actor = authenticate(s, token)
        assert (actor.username, actor.role) == ("alice", "operator")
        with db.write() as s:
            _, user = login(s, "carol", "s3cret-pass")
        assert user.role == "viewer"
    finally:
        db.dispose()
