"""The operator's loop: previews a confirmation is bound to; measurement sources and
corrections (withdrawn / superseded, never deleted); the sources an objective is made of.

Revision ID: operator1
Revises: harden1
Create Date: 2026-11-29 17:00:00
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op


revision: str = "operator1"
down_revision: str | None = "harden1"
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
    with op.batch_alter_table("experiments", schema=None) as batch_op:
        batch_op.add_column(sa.Column("objective_sources", sa.String(length=64), nullable=True))
    with op.batch_alter_table("measurements", schema=None) as batch_op:
        batch_op.add_column(sa.Column("withdrawn_at", sa.DateTime(timezone=True), nullable=True))
        batch_op.add_column(sa.Column("withdrawn_by", sa.String(length=64), nullable=True))
        batch_op.add_column(sa.Column("withdrawn_reason", sa.Text(), nullable=True))
        batch_op.add_column(sa.Column("supersedes_id", sa.Integer(), nullable=True))
        batch_op.create_foreign_key(
            "fk_measurements_supersedes_id", "measurements", ["supersedes_id"], ["id"]
        )
    # sources: who typed it (operator) / which worker (worker) -> what measured it
    op.execute(
        "UPDATE measurements SET source = 'imported' WHERE source = 'operator' AND trial_id IN "
        "(SELECT id FROM trials WHERE source = 'import')"
    )
    op.execute("UPDATE measurements SET source = 'tape' WHERE source = 'operator'")
    op.execute(
        "UPDATE measurements SET source = 'tracker' WHERE source = 'worker' AND trial_id IN "
        "(SELECT t.id FROM trials t JOIN experiments e ON e.id = t.experiment_id "
        "WHERE e.target = 'hardware')"
    )
    op.execute("UPDATE measurements SET source = 'sim' WHERE source = 'worker'")


def downgrade() -> None:
    op.execute("UPDATE measurements SET source = 'operator' WHERE source IN ('tape', 'imported')")
    op.execute("UPDATE measurements SET source = 'worker' WHERE source IN ('tracker', 'sim')")
    with op.batch_alter_table("measurements", schema=None) as batch_op:
        batch_op.drop_constraint("fk_measurements_supersedes_id", type_="foreignkey")
        batch_op.drop_column("supersedes_id")
        batch_op.drop_column("withdrawn_reason")
        batch_op.drop_column("withdrawn_by")
        batch_op.drop_column("withdrawn_at")
    # natively (SQLite ≥ 3.35): a batch copy of experiments would drop the old table, and with
    # foreign keys on that deletes every trial and measurement (ON DELETE CASCADE)
    op.drop_column("experiments", "objective_sources")
    op.drop_index("ix_previews_trial_id", table_name="previews")
    op.drop_table("previews")
