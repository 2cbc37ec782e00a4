"""Revision operator1 keeps every measurement: old sources mapped on upgrade and back on
downgrade (operator -> tape or imported, worker -> tracker on hardware or sim)."""

from __future__ import annotations

from app.db.migrate import downgrade, upgrade
from tests.db.legacy_rows import rows, seed


def _seed(path) -> None:
    seed(
        path,
        experiments=((1, "hardware"), (2, "sim")),
        trials=((1, 1, "optimizer"), (2, 2, "optimizer"), (3, 2, "import")),
        measurements=((1, 1, "operator"), (2, 1, "worker"), (3, 2, "worker"), (4, 3, "operator")),
    )


def _sources(path) -> list[tuple[int, str]]:
    return rows(path, "SELECT id, source FROM measurements ORDER BY id")


def test_sources_are_mapped_and_nothing_is_lost_either_way(tmp_path):
    path = tmp_path / "m.db"
    url = f"sqlite:///{path}"
    upgrade(url, "harden1")
    _seed(path)
    upgrade(url, "operator1")
    assert _sources(path) == [(1, "tape"), (2, "tracker"), (3, "sim"), (4, "imported")]
    downgrade(url, "harden1")
    assert _sources(path) == [(1, "operator"), (2, "worker"), (3, "worker"), (4, "operator")]
