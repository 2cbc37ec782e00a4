"""The service's one error hierarchy; app.api maps each class to its HTTP status in one place."""

from __future__ import annotations

from typing import Any


class ServiceError(Exception):
    """Base of every domain error; ``str(err)`` is the one-line message a client sees.

    ``keep_changes``: ``Database.write`` commits what the transaction did before the error
    (a lease sweep before a LeaseLost) instead of rolling it back."""

    status_code = 400
    code = "bad_request"
    keep_changes = False


class InvalidInput(ServiceError):
    """The request is well formed but its content is wrong (NaN, out of range, wrong length)."""

    status_code = 422
    code = "invalid_input"


class Unauthorized(ServiceError):
    """No valid token or password."""

    status_code = 401
    code = "unauthorized"


class Forbidden(ServiceError):
    """Authenticated, but this role may not do this."""

    status_code = 403
    code = "forbidden"


class NotFound(ServiceError):
    """An unknown id."""

    status_code = 404
    code = "not_found"


class Conflict(ServiceError):
    """The request conflicts with the current state (budget reached, lease lost, ...)."""

    status_code = 409
    code = "conflict"


class IllegalTransition(Conflict):
    """A trial status change the lifecycle table does not allow; names the current state."""

    code = "illegal_transition"

    def __init__(self, message: str, *, current: str, requested: str | None = None) -> None:
        super().__init__(message)
        self.current = current
        self.requested = requested


class DuplicateRequest(Conflict):
    """The same Idempotency-Key (or lease result) was already applied; nothing stored again.

    ``receipt``: the reply the first request got, when it was kept (a client that lost it
    to a dropped connection gets it back with the 409).
    """

    code = "duplicate_request"
    keep_changes = True

    def __init__(self, message: str, *, receipt: dict[str, Any] | None = None) -> None:
        super().__init__(message)
        self.receipt = receipt


class LeaseLost(Conflict):
    """A heartbeat or result for a lease that expired or was revoked."""

    code = "lease_lost"
    keep_changes = True


class SafetyViolation(ServiceError):
    """A pressure schedule outside the experiment's limits (422)."""

    status_code = 422
    code = "safety_violation"


class ConfirmationMismatch(SafetyViolation):
    """A confirmation whose hash is not the trial's current schedule, or a stale one (409)."""

    status_code = 409
    code = "confirmation_mismatch"


class NotPreviewed(ConfirmationMismatch):
    """A confirmation of a schedule this operator has not previewed (409)."""

    code = "not_previewed"


class PayloadTooLarge(ServiceError):
    """A body or upload beyond ``max_body_bytes``."""

    status_code = 413
    code = "payload_too_large"
