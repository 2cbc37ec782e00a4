"""The measurement write path: SQL-level inserts kept consistent with ORM objects in the session."""

from __future__ import annotations

import pytest
from sqlalchemy import select

from app.db.models import AuditLog, Experiment, Trial
from app.service import lifecycle as lc
from app.service.errors import DuplicateRequest
from app.service.experiments import touch
from app.service.measurements import add_measurements, store_measurement
from app.service.schemas import MeasurementsIn

from .conftest import OPERATOR


def _post(db, trial_id: int, values: list[float], key: str):
    body = MeasurementsIn(repeats=[{"value": v, "unit": "m/s"} for v in values])
    with db.write() as s:
        return add_measurements(s, trial_id, body, idempotency_key=key, actor=OPERATOR)


def _version(db, exp_id: int) -> int:
    with db.read() as s:
        return s.get(Experiment, exp_id).version


def test_each_post_bumps_the_version_once_and_keeps_every_repeat(db, make_experiment, make_trial):
    exp_id = make_experiment()
    tid = make_trial(exp_id, status=lc.QUEUED)
    v0 = _version(db, exp_id)
    first = _post(db, tid, [2.0, 4.0], "k1")
    assert first.status == lc.COMPLETED and first.objective == 3.0
    assert _version(db, exp_id) == v0 + 1
    second = _post(db, tid, [6.0], "k2")
    assert [m.value for m in second.stored] == [6.0]
    assert second.n_measurements == 3 and second.objective == 4.0
    assert second.stored[0].id > max(m.id for m in first.stored)
    assert _version(db, exp_id) == v0 + 2
    with pytest.raises(DuplicateRequest):
        _post(db, tid, [6.0], "k2")
    assert _version(db, exp_id) == v0 + 2
    with db.read() as s:
        actions = list(
            s.scalars(select(AuditLog.action).where(AuditLog.trial_id == tid).order_by(AuditLog.id))
        )
        stored = s.get(Trial, tid)
        assert stored.objective == 4.0 and stored.n_measurements == 3
    # audit rows follow the order of events: the repeats are recorded, then the completion
    assert actions[-3:] == ["trial.measure", "trial.completed", "trial.measure"]


def test_version_bump_when_the_experiment_is_already_loaded(db, make_experiment, make_trial):
    """A loaded experiment is touched on the object, so a later touch cannot repeat a number."""
    exp_id = make_experiment()
    tid = make_trial(exp_id, status=lc.COMPLETED)
    v0 = _version(db, exp_id)
    body = MeasurementsIn(repeats=[{"value": 1.0, "unit": "m/s"}])
    with db.write() as s:
        exp = s.get(Experiment, exp_id)
        add_measurements(s, tid, body, idempotency_key="k-loaded", actor=OPERATOR)
        touch(exp)
        s.commit()
    assert _version(db, exp_id) == v0 + 2


def test_a_loaded_repeats_collection_is_not_left_stale(db, make_experiment, make_trial):
    exp_id = make_experiment()
    tid = make_trial(exp_id, status=lc.COMPLETED)
    with db.write() as s:
        trial = s.get(Trial, tid)
        assert trial.measurements == []  # loads the collection
        store_measurement(
            s, trial, [(1.5, "m/s", ""), (2.5, "m/s", "")], actor=OPERATOR, source="sim"
        )
        assert [m.value for m in trial.measurements] == [1.5, 2.5]
        assert trial.objective == 2.0 and trial.n_measurements == 2
        s.commit()


def test_a_trial_loaded_in_the_session_is_kept_in_step(db, make_experiment, make_trial):
    """The post writes the row in SQL; a Trial the session already holds sees the new numbers
    at once, with nothing left to flush."""
    exp_id = make_experiment()
    tid = make_trial(exp_id, status=lc.COMPLETED)
    body = MeasurementsIn(repeats=[{"value": 1.0, "unit": "m/s"}, {"value": 3.0, "unit": "m/s"}])
    with db.write() as s:
        trial = s.get(Trial, tid)
        receipt = add_measurements(s, tid, body, idempotency_key="k-held", actor=OPERATOR)
        assert (trial.objective, trial.n_measurements) == (2.0, 2)
        assert trial.objective_sem == pytest.approx(1.0)
        assert not s.dirty
    assert receipt.objective == 2.0 and [m.value for m in receipt.stored] == [1.0, 3.0]
    with db.read() as s:
        assert s.get(Trial, tid).objective == 2.0


def test_store_measurement_leaves_an_orm_trial_clean(db, make_experiment, make_trial):
    exp_id = make_experiment()
    tid = make_trial(exp_id, status=lc.COMPLETED)
    with db.write() as s:
        trial = s.get(Trial, tid)
        stored = store_measurement(s, trial, [(4.0, "m/s", "")], actor=OPERATOR, source="sim")
        assert [m.value for m in stored] == [4.0] and trial.objective == 4.0
        assert trial not in s.dirty  # in step with its row: the UPDATE already ran
        s.rollback()
    with db.read() as s:
        assert s.get(Trial, tid).objective is None  # and it was part of the transaction
