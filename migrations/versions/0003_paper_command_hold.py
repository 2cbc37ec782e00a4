"""Experiments say how their schedule rows are applied: held (zero) or ramped (linear).

Existing experiments ran with each row held for its step, so they get "zero" and keep their
meaning.

Revision ID: paper1
Revises: 0002
Create Date: 2026-11-29 17:00:00
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "paper1"
down_revision: str | None = "0002"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table("experiments", schema=None) as batch_op:
        batch_op.add_column(
            sa.Column("command_hold", sa.String(length=16), nullable=False, server_default="zero")
        )


def downgrade() -> None:
    with op.batch_alter_table("experiments", schema=None) as batch_op:
        batch_op.drop_column("command_hold")
