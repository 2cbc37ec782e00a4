"""Service-level fixtures: a Database over a migrated SQLite file and factories for test data."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Any

import pytest

from app.db.models import Trial
from app.db.session import Database
from app.service import experiments, trials
from app.service.auth import Actor
from app.service.schemas import ExperimentCreate

OPERATOR = Actor("olivia", "operator")


@pytest.fixture
def db(migrated_db: str) -> Iterator[Database]:
    """The service's Database over a freshly migrated SQLite file."""
    database = Database(migrated_db)
    yield database
    database.dispose()


@pytest.fixture
def make_experiment(db: Database) -> Callable[..., int]:
    """Create an experiment (sim tip_speed, P=3, random search by default); returns its id."""

    def factory(**fields: Any) -> int:
        spec = {"name": "test", "task": "tip_speed", "levels": 3, "method": "random", **fields}
        if spec.get("target") == "hardware" and "limits" not in spec:
            spec["limits"] = {"nominal_pa": 100_000.0, "max_step_pa": 30_000.0}
        with db.write() as s:
            return experiments.create_experiment(s, ExperimentCreate(**spec), actor=OPERATOR).id

    return factory


@pytest.fixture
def make_trial(db: Database) -> Callable[..., int]:
    """Attach a trial with θ (default all 0.5) and force its status; returns its id."""

    def factory(experiment_id: int, status: str | None = None, theta: Any = None) -> int:
        with db.write() as s:
            exp = experiments.get_experiment(s, experiment_id)
            dim = exp.horizon + int(exp.with_release)
            t = trials.attach(s, experiment_id, theta or [0.5] * dim, note="", actor=OPERATOR)
        if status is not None:
            with db.write() as s:
                row = s.get(Trial, t.id)
                assert row is not None
                row.status = status
        return t.id

    return factory
