"""A claim's own id on its leases, so a worker that retries a claim whose answer it never got
(the server went down after committing it) gets the same leases back instead of stranding them.

Revision ID: claim1
Revises: twin1
Create Date: 2026-11-30 03:00:00
"""

from __future__ import annotations

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "claim1"
down_revision: str | None = "twin1"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    # natively: a nullable column with no default, on every backend
    op.add_column("leases", sa.Column("claim_id", sa.String(length=64), nullable=True))
    op.create_index("ix_leases_claim_id", "leases", ["claim_id"], unique=False)


def downgrade() -> None:
    op.drop_index("ix_leases_claim_id", table_name="leases")
    op.drop_column("leases", "claim_id")  # SQLite ≥ 3.35: natively, once no index names it
