"""The ``fast`` preset's physics changed (session 12: disk contacts within each continuum joint,
and the welded cube's fingers strike the floor); its old physics is the preset ``fast-r1``. Rows
stored under ``fast`` before this revision were simulated with the old physics, so they are
renamed ``fast-r1``: an experiment goes on with the physics it started with, and a preview or a
twin keeps saying what it ran.

Revision ID: presetr1
Revises: claim1
Create Date: 2026-11-30 15:00:00
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "presetr1"
down_revision: str | None = "claim1"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

#: the tables with a ``sim_preset`` column
TABLES = ("experiments", "trial_twins", "previews")


def _rename(old: str, new: str) -> None:
    for table in TABLES:
        op.execute(
            sa.text(f"UPDATE {table} SET sim_preset = :new WHERE sim_preset = :old").bindparams(
                old=old, new=new
            )
        )


def upgrade() -> None:
    _rename("fast", "fast-r1")


def downgrade() -> None:
    # code before this revision has no ``fast-r1``; its ``fast`` is that physics. Rows made
    # with today's ``fast`` have no name there: they keep it (and say so by being newer).
    _rename("fast-r1", "fast")
