"""The operator's loop: previews a confirmation is bound to; measurement sources and
corrections (withdrawn / superseded, never deleted); the sources an objective is made of.

Revision ID: operator1
Revises: 0002
Create Date: 2026-11-29 17:00:00
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op


revision: str = "operator1"
down_revision: str | None = "0002"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table(
        "previews",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("trial_id", sa.Integer(), nullable=False),
        sa.Column("schedule_hash", sa.String(length=64), nullable=False),
        sa.Column("hold", sa.String(length=64), nullable=True),
        sa.Column("sim_preset", sa.String(length=32), nullable=False),
        sa.Column("job_id", sa.String(length=32), nullable=False),
        sa.Column("predicted_objective", sa.Float(), nullable=True),
        sa.Column("previewed_by", sa.String(length=64), nullable=False),
        sa.Column("previewed_at", sa.DateTime(timezone=True), nullable=False),
        sa.ForeignKeyConstraint(["trial_id"], ["trials.id"], ondelete="CASCADE"),
        sa.PrimaryKeyConstraint("id"),
    )
    op.create_index("ix_previews_trial_id", "previews", ["trial_id"], unique=False)


def downgrade() -> None:
    op.drop_index("ix_previews_trial_id", table_name="previews")
    op.drop_table("previews")
