"""Revision twin1 (sim prior link, suggestion basis, sim twins) keeps every experiment and
trial both ways: no table copy that would cascade-delete trials."""

from __future__ import annotations

import sqlite3

from app.db.migrate import downgrade, upgrade
from tests.db.legacy_rows import NOW, seed
from tests.db.legacy_rows import rows as _rows


def _seed(path) -> None:
    seed(
        path,
        experiments=((1, "hardware"), (2, "sim")),
        trials=((1, 1, "optimizer"), (2, 2, "optimizer"), (3, 2, "optimizer")),
        measurements=((1, 1, "tracker"),),
        task="tip_speed",
        preset="fast",
        unit="m/s",
    )


def _columns(path, table: str) -> set[str]:
    return {r[1] for r in _rows(path, f"PRAGMA table_info({table})")}


def test_twin1_up_and_down_with_data(tmp_path):
    path = tmp_path / "m.db"
    url = f"sqlite:///{path}"
    upgrade(url, "drift1")
    _seed(path)
    upgrade(url, "twin1")
    assert "sim_prior_experiment_id" in _columns(path, "experiments")
    assert "suggestion_basis" in _columns(path, "trials")
    # old rows: no link, no basis; the new columns take data, the link is a foreign key
    assert _rows(path, "SELECT sim_prior_experiment_id FROM experiments") == [(None,), (None,)]
    c = sqlite3.connect(path)
    c.execute("PRAGMA foreign_keys = ON")
    c.execute("UPDATE experiments SET sim_prior_experiment_id = 2 WHERE id = 1")
    c.execute("""UPDATE trials SET suggestion_basis = '{"model": "multitask"}' WHERE id = 1""")
    c.execute(
        "INSERT INTO trial_twins (trial_id, kind, schedule_hash, sim_preset, command_hold,"
        " objective_rule, status, predicted_objective, bend_limit_hits, created_at)"
        " VALUES (1, 'executed', 'h', 'fast', 'zero', 'paper', 'done', 1.4, '[0]', ?)",
        (NOW,),
    )
    try:
        c.execute("UPDATE experiments SET sim_prior_experiment_id = 99 WHERE id = 1")
        raise AssertionError("a link to a missing experiment was stored")
    except sqlite3.IntegrityError:
        pass
    c.commit()
    c.close()
    downgrade(url, "drift1")
    assert "sim_prior_experiment_id" not in _columns(path, "experiments")
    assert "suggestion_basis" not in _columns(path, "trials")
    assert "trial_twins" not in {r[0] for r in _rows(path, "SELECT name FROM sqlite_master")}
    # nothing else lost
    assert _rows(path, "SELECT id, objective FROM trials ORDER BY id") == [
        (1, 1.5),
        (2, 1.5),
        (3, 1.5),
    ]
    assert _rows(path, "SELECT count(*) FROM measurements") == [(1,)]
    assert _rows(path, "SELECT count(*) FROM experiments") == [(2,)]
    upgrade(url)
    assert "sim_prior_experiment_id" in _columns(path, "experiments")
