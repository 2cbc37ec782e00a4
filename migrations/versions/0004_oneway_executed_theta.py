"""One rule for the executed θ: the planned θ when the trial ran its plan.

Before, a worker's result stored the centre of the θ bins of what it ran, while a run in the
service and an import stored the planned θ. Now every path stores ``Policy.executed_theta``:
the planned θ when what ran has the planned actions and release step, else the centre of the
bins of what ran. Rows written under the old rule are rewritten: a stored executed θ whose
actions and release step equal the planned ones becomes the planned θ (rows whose actions
differ already hold the new rule's value). Downgrade puts the bin centres back on trials that
a worker reported (a completed lease).

The arithmetic is ``app.policy``'s, written out here so this revision never changes with it:
M = P^6 actions, action = min(⌊θ_t·M⌋, M − 1), release index = min(⌊θ_H·H⌋, H − 1),
bin centres (a + ½)/M and (r + ½)/H.

Revision ID: oneway1
Revises: paper1
Create Date: 2026-11-29 17:20:00
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "oneway1"
down_revision: str | None = "paper1"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

experiments = sa.table(
    "experiments",
    sa.column("id", sa.Integer),
    sa.column("levels", sa.Integer),
    sa.column("horizon", sa.Integer),
    sa.column("with_release", sa.Boolean),
)
trials = sa.table(
    "trials",
    sa.column("id", sa.Integer),
    sa.column("experiment_id", sa.Integer),
    sa.column("theta", sa.JSON),
    sa.column("executed_theta", sa.JSON),
)
leases = sa.table(
    "leases",
    sa.column("trial_id", sa.Integer),
    sa.column("status", sa.String),
)


def _grid(theta: Sequence[float], levels: int, horizon: int, with_release: bool) -> list[int]:
    """Action indices (H,) and the release index: what θ decodes to."""
    m = levels**6
    out = [min(math.floor(float(t) * m), m - 1) for t in theta[:horizon]]
    if with_release:
        out.append(min(math.floor(float(theta[horizon]) * horizon), horizon - 1))
    return out


def _centres(theta: Sequence[float], levels: int, horizon: int, with_release: bool) -> list[float]:
    """θ at the centres of its bins (the old rule's value for a worker's result)."""
    m = levels**6
    grid = _grid(theta, levels, horizon, with_release)
    out = [(float(a) + 0.5) / m for a in grid[:horizon]]
    if with_release:
        out.append((float(grid[horizon]) + 0.5) / horizon)
    return out


def _rows(only_worker_results: bool) -> list[sa.Row]:
    query = (
        sa.select(
            trials.c.id,
            trials.c.theta,
            trials.c.executed_theta,
            experiments.c.levels,
            experiments.c.horizon,
            experiments.c.with_release,
        )
        .join(experiments, experiments.c.id == trials.c.experiment_id)
        .where(trials.c.executed_theta.is_not(None))
        .order_by(trials.c.id)
    )
    if only_worker_results:
        reported = sa.select(leases.c.trial_id).where(leases.c.status == "completed")
        query = query.where(trials.c.id.in_(reported))
    return list(op.get_bind().execute(query))


def _store(trial_id: int, executed_theta: list[float]) -> None:
    op.get_bind().execute(
        trials.update().where(trials.c.id == trial_id).values(executed_theta=executed_theta)
    )


def upgrade() -> None:
    for row in _rows(only_worker_results=False):
        shape = (row.levels, row.horizon, bool(row.with_release))
        planned = [float(v) for v in row.theta]
        if list(row.executed_theta) != planned and _grid(row.executed_theta, *shape) == _grid(
            planned, *shape
        ):
            _store(row.id, planned)


def downgrade() -> None:
    for row in _rows(only_worker_results=True):
        shape = (row.levels, row.horizon, bool(row.with_release))
        old = _centres(row.executed_theta, *shape)
        if list(row.executed_theta) != old:
            _store(row.id, old)
