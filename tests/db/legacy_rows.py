"""Rows written with raw SQL into a database migrated to an older revision, for the tests that
migrate it up and down with data in it (the ORM's models are the newest revision's)."""

from __future__ import annotations

import sqlite3
from collections.abc import Iterable
from pathlib import Path

NOW = "2026-01-01 00:00:00"


def seed(
    path: Path,
    *,
    experiments: Iterable[tuple[int, str]],
    trials: Iterable[tuple[int, int, str]],
    measurements: Iterable[tuple[int, int, str]],
    task: str = "throw",
    preset: str = "reference",
    unit: str = "m",
) -> None:
    """experiments (id, target), trials (id, experiment id, source) completed with objective
    1.5, measurements (id, trial id, source) of 1.5 ``unit``; the columns every revision from
    0001 to harden1 has."""
    c = sqlite3.connect(path)
    with_release = int(task == "throw")
    for eid, target in experiments:
        c.execute(
            "INSERT INTO experiments (id, name, task, target, sim_preset, objective_unit, levels,"
            " horizon, with_release, method, n_initial, seed, optimizer_settings, status, notes,"
            " version, created_by, created_at, updated_at) VALUES (?, 'e', ?, ?, ?, ?, 3, 10, ?,"
            " 'random', 3, 0, '{}', 'active', '', 1, 'x', ?, ?)",
            (eid, task, target, preset, unit, with_release, NOW, NOW),
        )
    for tid, eid, source in trials:
        c.execute(
            'INSERT INTO trials (id, experiment_id, "index", status, status_reason, source, note,'
            " theta, pressure_schedule_pa, objective, n_measurements, attempts, created_by,"
            " created_at, updated_at) VALUES (?, ?, ?, 'completed', '', ?, '', '[]', '[]', 1.5,"
            " 0, 0, 'x', ?, ?)",
            (tid, eid, tid, source, NOW, NOW),
        )
    for mid, tid, source in measurements:
        c.execute(
            "INSERT INTO measurements (id, trial_id, value, unit, note, source, created_by,"
            " created_at) VALUES (?, ?, 1.5, ?, '', ?, 'x', ?)",
            (mid, tid, unit, source, NOW),
        )
    c.commit()
    c.close()


def rows(path: Path, sql: str) -> list[tuple]:
    """The rows ``sql`` selects."""
    c = sqlite3.connect(path)
    try:
        return c.execute(sql).fetchall()
    finally:
        c.close()
