"""Service tests: the actor they act as. Their fixtures (``db``, ``make_experiment``,
``make_trial``) are shared from tests/conftest.py."""

from __future__ import annotations

from app.service.auth import Actor

OPERATOR = Actor("olivia", "operator")
