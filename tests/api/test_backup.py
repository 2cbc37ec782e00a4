"""`handful backup` while the server runs and writes, and `handful restore` (issue 16,
finding 7): every committed measurement (WAL included) and the artifacts, checked."""

from __future__ import annotations

import sqlite3
import threading

from typer.testing import CliRunner

from app.cli import app as cli
from app.service import backup as bk


def test_backup_while_serving_then_restore(module_server, tmp_path):
    op = module_server.client("operator")
    exp = op.create_experiment(
        name="b", task="tip_speed", levels=3, method="random", sim_preset="fast"
    )
    first, *rest = op.suggest(exp["id"], n=8)
    op.run_trial(first["id"])  # a trajectory artifact
    for t in rest[:4]:
        op.add_measurements(t["id"], [{"value": 1.0, "unit": "m/s"}])
    before = sum(op.get_trial(t["id"])["n_measurements"] for t in [first, *rest])
    stop = threading.Event()

    def keep_writing() -> None:  # the server keeps committing during the backup
        i = 0
        while not stop.is_set():
            op2 = module_server.client("operator")
            op2.add_measurements(rest[4 + i % 3]["id"], [{"value": 2.0, "unit": "m/s"}])
            i += 1

    writer = threading.Thread(target=keep_writing)
    writer.start()
    runner = CliRunner()
    dest = tmp_path / "backup"
    try:
        r = runner.invoke(cli, ["backup", str(dest), "--data-dir", str(module_server.data_dir)])
    finally:
        stop.set()
        writer.join()
    assert r.exit_code == 0, r.output
    manifest = bk.verify(dest)
    rows = manifest["database"]["rows"]
    assert rows["measurements"] >= before  # what sat in the WAL is in the copy
    assert len(manifest["artifacts"]) == 1 and not manifest["missing_artifacts"]
    assert oct((dest / "handful.db").stat().st_mode & 0o777) == "0o600"
    # the copy is one consistent state: each trial's count matches its rows
    conn = sqlite3.connect(dest / "handful.db")
    bad = conn.execute(
        "SELECT count(*) FROM trials t WHERE t.n_measurements != "
        "(SELECT count(*) FROM measurements m WHERE m.trial_id = t.id)"
    ).fetchone()[0]
    conn.close()
    assert bad == 0
    # restore into a new data folder, refusing to overwrite one without --force
    target = tmp_path / "restored"
    r = runner.invoke(cli, ["restore", str(dest), "--data-dir", str(target)])
    assert r.exit_code == 0, r.output
    r = runner.invoke(cli, ["restore", str(dest), "--data-dir", str(target)])
    assert r.exit_code == 1 and "--force" in r.output
    conn = sqlite3.connect(target / "handful.db")
    assert conn.execute("SELECT count(*) FROM measurements").fetchone()[0] == rows["measurements"]
    conn.close()
    [rel] = manifest["artifacts"]
    assert (target / "artifacts" / rel).read_bytes() == (
        module_server.data_dir / "artifacts" / rel
    ).read_bytes()
    # a damaged backup is refused
    (dest / "artifacts" / rel).write_bytes(b"damaged")
    r = runner.invoke(cli, ["restore", str(dest), "--data-dir", str(tmp_path / "x")])
    assert r.exit_code == 1 and "does not match" in r.output
