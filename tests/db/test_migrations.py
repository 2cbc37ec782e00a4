"""The Alembic migrations: upgrade to head builds every table, downgrade to base removes them."""

from __future__ import annotations

import sqlite3

import numpy as np
import pytest
from sqlalchemy import inspect, select, update

from app.db.base import Base
from app.db.migrate import downgrade, upgrade
from app.db.session import Database, make_engine
from app.service import trials
from app.service.auth import Actor


def _tables(url: str) -> set[str]:
    engine = make_engine(url)
    try:
        return set(inspect(engine).get_table_names())
    finally:
        engine.dispose()


def test_upgrade_head_then_downgrade_base_then_upgrade_again(tmp_path):
    url = f"sqlite:///{tmp_path / 'm.db'}"
    upgrade(url)
    model_tables = set(Base.metadata.tables)
    assert model_tables <= _tables(url)
    assert "alembic_version" in _tables(url)
    downgrade(url, "base")
    assert _tables(url) & model_tables == set()
    upgrade(url)
    assert model_tables <= _tables(url)


def test_migrated_schema_matches_the_models(tmp_path):
    """No model change without a migration: autogenerate finds nothing to do at head."""
    from alembic.autogenerate import compare_metadata
    from alembic.migration import MigrationContext

    url = f"sqlite:///{tmp_path / 'm.db'}"
    upgrade(url)
    engine = make_engine(url)
    with engine.connect() as conn:
        diff = compare_metadata(MigrationContext.configure(conn), Base.metadata)
    engine.dispose()
    assert diff == []


def test_sqlite_runs_in_wal_mode_with_foreign_keys(migrated_db):
    db = Database(migrated_db)
    with db.read() as s:
        assert s.connection().exec_driver_sql("PRAGMA journal_mode").scalar() == "wal"
        assert s.connection().exec_driver_sql("PRAGMA foreign_keys").scalar() == 1
    db.dispose()


def test_audit_log_is_append_only_in_the_database(migrated_db):
    path = migrated_db.removeprefix("sqlite:///")
    con = sqlite3.connect(path)
    con.execute(
        "INSERT INTO audit_log (at, actor, action, entity, entity_id) "
        "VALUES ('2026-01-01 00:00:00', 'a', 'x', 'trial', '1')"
    )
    con.commit()
    for sql in ("UPDATE audit_log SET actor = 'b'", "DELETE FROM audit_log"):
        with pytest.raises(sqlite3.IntegrityError, match="append-only"):
            con.execute(sql)
    con.close()


def test_command_hold_revision_gives_old_experiments_zero_and_downgrades(tmp_path):
    url = f"sqlite:///{tmp_path / 'm.db'}"
    upgrade(url, "0002")
    path = url.removeprefix("sqlite:///")
    con = sqlite3.connect(path)
    cols = [r for r in con.execute("PRAGMA table_info(experiments)") if r[1] != "id"]
    assert "command_hold" not in [r[1] for r in cols]
    values = {
        r[1]: (0 if r[2].upper() in ("INTEGER", "BOOLEAN", "FLOAT") else "{}" if r[2] == "JSON"
               else "2026-01-01 00:00:00" if r[2] in ("DATETIME", "TIMESTAMP") else "x")
        for r in cols if r[3]  # NOT NULL columns
    }  # fmt: skip
    con.execute(
        f"INSERT INTO experiments ({', '.join(values)}) VALUES ({', '.join('?' * len(values))})",
        list(values.values()),
    )
    con.commit()
    con.close()
    upgrade(url)
    con = sqlite3.connect(path)
    assert con.execute("SELECT command_hold FROM experiments").fetchall() == [("zero",)]
    con.close()
    downgrade(url, "0002")
    con = sqlite3.connect(path)
    assert "command_hold" not in [r[1] for r in con.execute("PRAGMA table_info(experiments)")]
    assert con.execute("SELECT COUNT(*) FROM experiments").fetchone() == (1,)
    con.close()


def test_executed_theta_rows_are_rewritten_to_the_one_rule_and_back(db, make_experiment):
    """Revision oneway1: a worker's result stored as the centre of the planned bins becomes
    the planned θ; one that ran other actions, and a run in the service, stay as they are."""
    from datetime import timedelta

    from alembic.script import ScriptDirectory

    from app.db.base import utcnow
    from app.db.migrate import alembic_config
    from app.db.models import Lease, Trial
    from app.policy import Policy

    url = str(db.engine.url)
    exp_id = make_experiment(task="throw", levels=3)
    policy = Policy(levels=3, with_release=True)
    rng = np.random.default_rng(0)
    planned = [rng.random(11) for _ in range(3)]
    centre = [policy.theta_from_actions(*policy.actions_from_theta(th)) for th in planned]
    other = policy.theta_from_actions(np.arange(10), 3)  # actions the plan did not have
    old_rule = {0: centre[0], 1: other, 2: planned[2]}  # worker, worker, run in the service
    ids = []
    with db.write() as s:
        for i, th in enumerate(planned):
            t = trials.attach(s, exp_id, th.tolist(), note="", actor=Actor("olivia", "operator"))
            ids.append(t.id)
            if i < 2:
                now = utcnow()
                s.add(
                    Lease(
                        id=f"lease-{i}",
                        trial_id=t.id,
                        worker_id="w",
                        claimed_by="worker",
                        status="completed",
                        attempt=1,
                        expires_at=now + timedelta(minutes=1),
                    )
                )
    before = ScriptDirectory.from_config(alembic_config(url)).get_revision("oneway1").down_revision

    # column by column, not whole rows: below head the trials table lacks later columns
    def stored() -> list[list[float]]:
        with db.read() as s:
            return [list(s.scalar(select(Trial.executed_theta).where(Trial.id == i))) for i in ids]

    downgrade(url, before)
    with db.write() as s:
        for i, tid in enumerate(ids):
            s.execute(
                update(Trial)
                .where(Trial.id == tid)
                .values(executed_theta=[float(v) for v in old_rule[i]])
            )
    upgrade(url, "oneway1")
    assert stored() == [planned[0].tolist(), other.tolist(), planned[2].tolist()]
    downgrade(url, before)
    assert stored() == [centre[0].tolist(), other.tolist(), planned[2].tolist()]
    upgrade(url)


def test_drift_revision_adds_reference_settings_and_downgrades_reference_trials(tmp_path):
    """Revision drift1: old experiments get no drift check, m = 3 and no age weighting; on
    the way down a reference trial becomes an operator's θ, and no row is lost."""
    url = f"sqlite:///{tmp_path / 'm.db'}"
    upgrade(url, "operator1")
    path = url.removeprefix("sqlite:///")
    con = sqlite3.connect(path)
    now = "2026-01-01 00:00:00"
    con.execute(
        "INSERT INTO experiments (id, name, task, target, sim_preset, command_hold, "
        "objective_unit, levels, horizon, with_release, method, n_initial, seed, "
        "optimizer_settings, status, notes, version, created_by, created_at, updated_at) "
        "VALUES (1, 'e', 'tip_speed', 'hardware', 'fast', 'zero', 'm/s', 3, 10, 0, 'random', "
        f"11, 0, '{{}}', 'active', '', 1, 'olivia', '{now}', '{now}')"
    )
    for i in (1, 2):
        con.execute(
            'INSERT INTO trials (id, experiment_id, "index", status, status_reason, source, '
            "note, theta, pressure_schedule_pa, n_measurements, attempts, created_by, "
            f"created_at, updated_at) VALUES ({i}, 1, {i}, 'completed', '', 'operator', '', "
            f"'[0.5]', '[[1.0]]', 0, 0, 'olivia', '{now}', '{now}')"
        )
    con.commit()
    con.close()
    upgrade(url, "drift1")
    con = sqlite3.connect(path)
    cols = (
        "reference_every, reference_theta_from, reference_trial_id, reference_theta, "
        "drift_baseline_n, drift_tolerance, age_halflife_trials"
    )
    assert con.execute(f"SELECT {cols} FROM experiments").fetchall() == [
        (None, None, None, None, 3, None, None)
    ]
    con.execute(
        "UPDATE experiments SET reference_every = 3, reference_theta_from = 'trial', "
        "reference_trial_id = 1, reference_theta = '[0.5]', drift_tolerance = 0.1, "
        "age_halflife_trials = 20.0"
    )
    con.execute("UPDATE trials SET source = 'reference' WHERE id = 2")
    con.commit()
    con.close()
    downgrade(url, "operator1")
    con = sqlite3.connect(path)
    names = [r[1] for r in con.execute("PRAGMA table_info(experiments)")]
    assert not {"reference_every", "drift_baseline_n", "age_halflife_trials"} & set(names)
    assert con.execute("SELECT id, source FROM trials ORDER BY id").fetchall() == [
        (1, "operator"),
        (2, "operator"),
    ]
    assert con.execute("SELECT COUNT(*) FROM experiments").fetchone() == (1,)
    con.close()
    upgrade(url)


def test_fast_preset_rows_become_fast_r1_and_back(tmp_path):
    """Revision presetr1: experiments, previews and twins stored under ``fast`` were simulated
    with its first physics, now the preset ``fast-r1``; the way down gives the name back, and
    other presets are left alone."""
    url = f"sqlite:///{tmp_path / 'm.db'}"
    upgrade(url, "claim1")
    path = url.removeprefix("sqlite:///")
    con = sqlite3.connect(path)
    now = "2026-01-01 00:00:00"
    for i, preset in ((1, "fast"), (2, "reference")):
        con.execute(
            "INSERT INTO experiments (id, name, task, target, sim_preset, command_hold, "
            "objective_unit, levels, horizon, with_release, method, n_initial, seed, "
            "optimizer_settings, status, notes, version, created_by, created_at, updated_at) "
            f"VALUES ({i}, 'e', 'tip_speed', 'sim', '{preset}', 'zero', 'm/s', 3, 10, 0, "
            f"'random', 11, 0, '{{}}', 'active', '', 1, 'olivia', '{now}', '{now}')"
        )
    con.execute(
        'INSERT INTO trials (id, experiment_id, "index", status, status_reason, source, '
        "note, theta, pressure_schedule_pa, n_measurements, attempts, created_by, "
        f"created_at, updated_at) VALUES (1, 1, 1, 'pending', '', 'optimizer', '', "
        f"'[0.5]', '[[1.0]]', 0, 0, 'olivia', '{now}', '{now}')"
    )
    con.execute(
        "INSERT INTO previews (id, trial_id, schedule_hash, hold, sim_preset, job_id, "
        f"previewed_by, previewed_at) VALUES (1, 1, 'h', 'zero', 'fast', 'j', 'olivia', '{now}')"
    )
    con.commit()
    con.close()

    def presets() -> list[tuple[str, ...]]:
        con = sqlite3.connect(path)
        try:
            exps = con.execute("SELECT sim_preset FROM experiments ORDER BY id").fetchall()
            return [*exps, *con.execute("SELECT sim_preset FROM previews").fetchall()]
        finally:
            con.close()

    upgrade(url, "presetr1")
    assert presets() == [("fast-r1",), ("reference",), ("fast-r1",)]
    downgrade(url, "claim1")
    assert presets() == [("fast",), ("reference",), ("fast",)]
    upgrade(url)
