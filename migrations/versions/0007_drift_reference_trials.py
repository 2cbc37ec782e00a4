"""Drift checks: a reference θ every k hardware trials (``reference_*``, ``drift_*`` on
experiments; a reference trial has ``source = 'reference'``) and the BO's weighing of data by
age (``experiments.age_halflife_trials``).

Revision ID: drift1
Revises: operator1
Create Date: 2026-11-29 20:00:00
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "drift1"
down_revision: str | None = "operator1"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

_COLUMNS = (
    sa.Column("age_halflife_trials", sa.Float(), nullable=True),
    sa.Column("reference_every", sa.Integer(), nullable=True),
    sa.Column("reference_theta_from", sa.String(length=16), nullable=True),
    sa.Column("reference_trial_id", sa.Integer(), nullable=True),
    sa.Column("reference_theta", sa.JSON(), nullable=True),
    sa.Column("drift_baseline_n", sa.Integer(), nullable=False, server_default="3"),
    sa.Column("drift_tolerance", sa.Float(), nullable=True),
)


def upgrade() -> None:
    # natively (ADD COLUMN): a batch copy of experiments would drop the old table, and with
    # foreign keys on that deletes every trial and measurement (ON DELETE CASCADE)
    for column in _COLUMNS:
        op.add_column("experiments", column)


def downgrade() -> None:
    # before this revision a reference trial was an operator's θ
    op.execute("UPDATE trials SET source = 'operator' WHERE source = 'reference'")
    for column in reversed(_COLUMNS):
        op.drop_column("experiments", column.name)
