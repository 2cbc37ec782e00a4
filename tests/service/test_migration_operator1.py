"""Revision operator1 keeps every measurement: old sources mapped on upgrade and back on
downgrade (operator -> tape or imported, worker -> tracker on hardware or sim)."""

from __future__ import annotations

import sqlite3

from app.db.migrate import downgrade, upgrade

NOW = "2026-01-01 00:00:00"


def _seed(path) -> None:
    c = sqlite3.connect(path)
    for eid, target in ((1, "hardware"), (2, "sim")):
        c.execute(
            "INSERT INTO experiments (id, name, task, target, sim_preset, objective_unit, levels,"
            " horizon, with_release, method, n_initial, seed, optimizer_settings, status, notes,"
            " version, created_by, created_at, updated_at) VALUES (?, 'e', 'throw', ?,"
            " 'reference', 'm', 3, 10, 1, 'random', 3, 0, '{}', 'active', '', 1, 'x', ?, ?)",
            (eid, target, NOW, NOW),
        )
    for tid, eid, source in ((1, 1, "optimizer"), (2, 2, "optimizer"), (3, 2, "import")):
        c.execute(
            'INSERT INTO trials (id, experiment_id, "index", status, status_reason, source, note,'
            " theta, pressure_schedule_pa, n_measurements, attempts, created_by, created_at,"
            " updated_at) VALUES (?, ?, ?, 'completed', '', ?, '', '[]', '[]', 0, 0, 'x', ?, ?)",
            (tid, eid, tid, source, NOW, NOW),
        )
    old = ((1, 1, "operator"), (2, 1, "worker"), (3, 2, "worker"), (4, 3, "operator"))
    for mid, tid, source in old:
        c.execute(
            "INSERT INTO measurements (id, trial_id, value, unit, note, source, created_by,"
            " created_at) VALUES (?, ?, 1.0, 'm', '', ?, 'x', ?)",
            (mid, tid, source, NOW),
        )
    c.commit()
    c.close()


def _sources(path) -> list[tuple[int, str]]:
    c = sqlite3.connect(path)
    try:
        return c.execute("SELECT id, source FROM measurements ORDER BY id").fetchall()
    finally:
        c.close()


def test_sources_are_mapped_and_nothing_is_lost_either_way(tmp_path):
    path = tmp_path / "m.db"
    url = f"sqlite:///{path}"
    upgrade(url, "harden1")
    _seed(path)
    upgrade(url, "operator1")
    assert _sources(path) == [(1, "tape"), (2, "tracker"), (3, "sim"), (4, "imported")]
    downgrade(url, "harden1")
    assert _sources(path) == [(1, "operator"), (2, "worker"), (3, "worker"), (4, "operator")]
