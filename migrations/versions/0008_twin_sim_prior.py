"""From simulation to the robot: a hardware experiment's linked sim experiment (its sim prior),
what each suggestion leaned on, and each hardware trial's sim twin.

Revision ID: twin1
Revises: drift1
Create Date: 2026-11-29 20:00:00
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "twin1"
down_revision: str | None = "drift1"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

FK = "fk_experiments_sim_prior_experiment_id_experiments"


def upgrade() -> None:
    op.create_table(
        "trial_twins",
        sa.Column("id", sa.Integer(), nullable=False),
        sa.Column("trial_id", sa.Integer(), nullable=False),
        sa.Column("kind", sa.String(length=16), nullable=False),
        sa.Column("schedule_hash", sa.String(length=64), nullable=False),
        sa.Column("sim_preset", sa.String(length=32), nullable=False),
        sa.Column("command_hold", sa.String(length=16), nullable=False),
        sa.Column("objective_rule", sa.String(length=16), nullable=False),
        sa.Column("sim_experiment_id", sa.Integer(), nullable=True),
        sa.Column("status", sa.String(length=16), nullable=False),
        sa.Column("error", sa.Text(), nullable=True),
        sa.Column("predicted_objective", sa.Float(), nullable=True),
        sa.Column("predicted_tip_speed", sa.Float(), nullable=True),
        sa.Column("bend_limit_hits", sa.JSON(), nullable=True),
        sa.Column("wall_s", sa.Float(), nullable=True),
        sa.Column("created_at", sa.DateTime(timezone=True), nullable=False),
        sa.ForeignKeyConstraint(
            ["trial_id"],
            ["trials.id"],
            name="fk_trial_twins_trial_id_trials",
            ondelete="CASCADE",
        ),
        sa.PrimaryKeyConstraint("id", name="pk_trial_twins"),
        sa.UniqueConstraint("trial_id", "kind", name="uq_trial_twins_trial_id"),
    )
    op.create_index("ix_trial_twins_trial_id", "trial_twins", ["trial_id"], unique=False)
    # Natively, never as a batch copy: copying experiments (or trials) drops the old table,
    # and with foreign keys on that deletes every trial and measurement (ON DELETE CASCADE).
    # SQLite adds a column with an inline REFERENCES clause when its default is NULL (no
    # ON DELETE: experiments are never deleted, and SQLite's reflection would not see it).
    if op.get_bind().dialect.name == "sqlite":
        op.execute(
            "ALTER TABLE experiments ADD COLUMN sim_prior_experiment_id INTEGER "
            f"CONSTRAINT {FK} REFERENCES experiments (id)"
        )
    else:
        op.add_column(
            "experiments", sa.Column("sim_prior_experiment_id", sa.Integer(), nullable=True)
        )
        op.create_foreign_key(FK, "experiments", "experiments", ["sim_prior_experiment_id"], ["id"])
    op.add_column("trials", sa.Column("suggestion_basis", sa.JSON(), nullable=True))


def downgrade() -> None:
    # natively (SQLite ≥ 3.35 drops a column that no index or constraint names)
    op.drop_column("trials", "suggestion_basis")
    if op.get_bind().dialect.name != "sqlite":
        op.drop_constraint(FK, "experiments", type_="foreignkey")
    # SQLite drops a column with its own REFERENCES clause natively (3.35+)
    op.drop_column("experiments", "sim_prior_experiment_id")
    op.drop_index("ix_trial_twins_trial_id", table_name="trial_twins")
    op.drop_table("trial_twins")
