"""PostgreSQL through the same URL setting: migrations, the API and row-locked claims.

A throwaway PostgreSQL cluster (Debian's ``postgresql`` package, installed by scripts/dev.sh)
is started on 127.0.0.1 for this module; the server gets it as ``HANDFUL_DATABASE_URL``.
"""

from __future__ import annotations

import glob
import os
import pwd
import shutil
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from sqlalchemy import inspect as sa_inspect

from app.client import HandfulAPIError
from app.db.migrate import downgrade, upgrade
from app.db.session import Database

from ..conftest import ServerHandle, claim_until_empty, free_port, seed_users

pytestmark = pytest.mark.slow


def _pg_bin() -> Path:
    found = sorted(glob.glob("/usr/lib/postgresql/*/bin/initdb"))
    if not found and shutil.which("initdb") is None:
        pytest.fail("PostgreSQL is not installed: `apt-get install postgresql` (scripts/dev.sh)")
    return Path(found[-1]).parent if found else Path(shutil.which("initdb")).parent  # type: ignore[arg-type]


def _as_pg_user(args: list[str]) -> list[str]:
    """initdb and postgres refuse to run as root: run them as the ``postgres`` user then."""
    if os.geteuid() != 0:
        return args
    return ["runuser", "-u", "postgres", "--", *args]


@pytest.fixture(scope="module")
def postgres_url(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """URL of an empty database in a fresh PostgreSQL cluster on a free loopback port."""
    pg = _pg_bin()
    root = tmp_path_factory.mktemp("pg")
    if os.geteuid() == 0:
        uid = pwd.getpwnam("postgres").pw_uid
        for p in (root, *root.parents):
            if p == Path("/"):
                break
            os.chmod(p, os.stat(p).st_mode | 0o005)  # the postgres user must reach it
        os.chown(root, uid, -1)
    data, port = root / "data", free_port()
    run = {"check": True, "capture_output": True}
    subprocess.run(
        _as_pg_user([str(pg / "initdb"), "-D", str(data), "-A", "trust", "-U", "handful"]), **run
    )
    opts = f"-p {port} -k {root} -c listen_addresses=127.0.0.1 -c fsync=on"
    subprocess.run(
        _as_pg_user(
            [
                str(pg / "pg_ctl"),
                "-D",
                str(data),
                "-o",
                opts,
                "-l",
                str(root / "log"),
                "-w",
                "start",
            ]
        ),
        **run,
    )
    try:
        subprocess.run(
            _as_pg_user(
                [
                    str(pg / "createdb"),
                    "-h",
                    "127.0.0.1",
                    "-p",
                    str(port),
                    "-U",
                    "handful",
                    "handful",
                ]
            ),
            **run,
        )
        yield f"postgresql+psycopg://handful@127.0.0.1:{port}/handful"
    finally:
        subprocess.run(
            _as_pg_user([str(pg / "pg_ctl"), "-D", str(data), "-m", "immediate", "stop"]),
            capture_output=True,
        )


def test_migrations_go_up_down_and_up_again(postgres_url):
    upgrade(postgres_url)
    db = Database(postgres_url)
    tables = set(sa_inspect(db.engine).get_table_names())
    assert {"experiments", "trials", "measurements", "audit_log", "leases"} <= tables
    db.dispose()
    downgrade(postgres_url, "base")
    db = Database(postgres_url)
    assert set(sa_inspect(db.engine).get_table_names()) <= {"alembic_version"}
    db.dispose()
    upgrade(postgres_url)


@pytest.fixture(scope="module")
def pg_server(postgres_url, tmp_path_factory) -> Iterator[ServerHandle]:
    upgrade(postgres_url)
    handle = ServerHandle(
        data_dir=tmp_path_factory.mktemp("pgdata"),
        port=free_port(),
        tokens=seed_users(postgres_url),
        env={"HANDFUL_DATABASE_URL": postgres_url, "HANDFUL_DASHBOARD_ENABLED": "0"},
    )
    handle.start()
    yield handle
    handle.close()


def test_the_api_runs_on_postgres_and_claims_never_collide(pg_server):
    op = pg_server.client("operator")
    exp = op.create_experiment(name="pg", task="tip_speed", levels=3, method="random")
    trials = op.suggest(exp["id"], n=10)
    assert {t["status"] for t in trials} == {"queued"}
    got = claim_until_empty(pg_server, n_workers=4)  # FOR UPDATE SKIP LOCKED: no trial twice
    assert sorted(got) == sorted(t["id"] for t in trials)

    t = trials[0]
    measured = op.add_measurements(
        t["id"],
        [{"value": 2.0, "unit": "m/s"}, {"value": 3.0, "unit": "m/s"}],
        idempotency_key="pg-1",
    )
    assert measured["n_measurements"] == 2 and measured["objective"] == 2.5
    with pytest.raises(HandfulAPIError) as dup:
        op.add_measurements(
            t["id"],
            [{"value": 2.0, "unit": "m/s"}, {"value": 3.0, "unit": "m/s"}],
            idempotency_key="pg-1",
        )
    assert dup.value.status == 409 and dup.value.code == "duplicate_request"
    assert op.get_trial(t["id"])["n_measurements"] == 2
    data = op.export(exp["id"], "json")
    assert len(data["trials"]) == 10 and len(data["measurements"]) == 2


def test_a_killed_server_on_postgres_keeps_every_committed_measurement(pg_server):
    op = pg_server.client("operator")
    exp = op.create_experiment(name="pg-restart", task="tip_speed", levels=3, method="random")
    [t] = op.suggest(exp["id"])
    op.add_measurements(t["id"], [{"value": 1.25, "unit": "m/s"}])
    pg_server.kill9()
    time.sleep(0.2)
    pg_server.start()
    after = pg_server.client("operator").get_trial(t["id"])
    assert after["status"] == "completed" and after["objective"] == 1.25
