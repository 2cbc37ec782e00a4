"""Every legal and every illegal trial status change, applied to real rows."""

from __future__ import annotations

import itertools

import pytest
from sqlalchemy import select

from app.db.models import AuditLog, Trial
from app.service import lifecycle as lc
from app.service.errors import IllegalTransition

PAIRS = list(itertools.product(lc.STATUSES, lc.STATUSES))
LEGAL = [(a, b) for a, b in PAIRS if b in lc.TRANSITIONS[a]]
ILLEGAL = [(a, b) for a, b in PAIRS if b not in lc.TRANSITIONS[a]]


def test_table_covers_every_status_and_terminals_are_final():
    assert set(lc.TRANSITIONS) == set(lc.STATUSES)
    for status, targets in lc.TRANSITIONS.items():
        assert targets <= set(lc.STATUSES), status
    for status in lc.TERMINAL:
        assert lc.TRANSITIONS[status] == frozenset()
    # the documented paths exist
    assert lc.can_transition(lc.PROPOSED, lc.AWAITING_CONFIRMATION)
    assert lc.can_transition(lc.AWAITING_CONFIRMATION, lc.QUEUED)
    assert lc.can_transition(lc.QUEUED, lc.RUNNING)
    assert lc.can_transition(lc.RUNNING, lc.COMPLETED)
    assert not lc.can_transition(lc.AWAITING_CONFIRMATION, lc.RUNNING)  # the hardware gate


@pytest.fixture
def trial_in(db, make_experiment, make_trial):
    exp_id = make_experiment()

    def factory(status: str) -> int:
        return make_trial(exp_id, status=status)

    return factory


@pytest.mark.parametrize(("current", "new"), LEGAL)
def test_legal_transition_is_applied_and_audited(db, trial_in, current, new):
    tid = trial_in(current)
    with db.write() as s:
        trial = s.get(Trial, tid)
        lc.transition(s, trial, new, actor="olivia", reason="because")
    with db.read() as s:
        trial = s.get(Trial, tid)
        assert trial.status == new
        assert trial.status_reason == "because"
        last = s.scalars(
            select(AuditLog).where(AuditLog.trial_id == tid).order_by(AuditLog.id.desc())
        ).first()
        assert (last.before, last.after, last.actor) == (current, new, "olivia")
        if new == lc.RUNNING:
            assert trial.started_at is not None
        if new in lc.TERMINAL:
            assert trial.finished_at is not None


@pytest.mark.parametrize(("current", "new"), ILLEGAL)
def test_illegal_transition_names_the_state_and_changes_nothing(db, trial_in, current, new):
    tid = trial_in(current)
    with db.read() as s:
        n_audit = len(list(s.scalars(select(AuditLog).where(AuditLog.trial_id == tid))))
    with pytest.raises(IllegalTransition) as info, db.write() as s:
        lc.transition(s, s.get(Trial, tid), new, actor="olivia")
    assert info.value.current == current
    assert f"is {current}" in str(info.value)
    with db.read() as s:
        assert s.get(Trial, tid).status == current
        assert len(list(s.scalars(select(AuditLog).where(AuditLog.trial_id == tid)))) == n_audit
