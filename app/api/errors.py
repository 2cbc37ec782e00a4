"""Errors → HTTP, in one place: domain errors as ``{"detail": "<words>", "code": "<kind>"}``;
request validation errors in FastAPI's list form (``loc``, ``msg``), made JSON-safe."""

from __future__ import annotations

import math
from typing import Any

from fastapi import FastAPI, Request
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from sqlalchemy.exc import OperationalError
from sqlalchemy.exc import TimeoutError as PoolTimeout

from app.service.errors import DuplicateRequest, IllegalTransition, ServiceError


def _json_safe(value: Any) -> Any:
    """Replace NaN/±inf (which JSON cannot carry) with their names, recursively."""
    if isinstance(value, float) and not math.isfinite(value):
        return repr(value)
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_json_safe(v) for v in value]
    return value


def install(app: FastAPI) -> None:
    """Register the error handlers on ``app``."""

    @app.exception_handler(ServiceError)
    async def _service_error(_request: Request, exc: ServiceError) -> JSONResponse:
        body: dict[str, Any] = {"detail": str(exc), "code": exc.code}
        if isinstance(exc, IllegalTransition):
            body["current_status"] = exc.current
        if isinstance(exc, DuplicateRequest) and exc.receipt is not None:
            body["receipt"] = exc.receipt
        headers = {"WWW-Authenticate": "Bearer"} if exc.status_code == 401 else None
        return JSONResponse(body, status_code=exc.status_code, headers=headers)

    busy = {"code": "database_busy"}

    @app.exception_handler(PoolTimeout)
    async def _writer_queue_full(_request: Request, exc: PoolTimeout) -> JSONResponse:
        detail = "the database is busy: another write held it too long; nothing was stored, retry"
        return JSONResponse(
            {"detail": detail, **busy}, status_code=503, headers={"Retry-After": "1"}
        )

    @app.exception_handler(OperationalError)
    async def _database_error(_request: Request, exc: OperationalError) -> JSONResponse:
        if "locked" in str(exc.orig) or "busy" in str(exc.orig):  # another process's writer
            detail = "the database is locked by another program; nothing was stored, retry"
            return JSONResponse(
                {"detail": detail, **busy}, status_code=503, headers={"Retry-After": "1"}
            )
        raise exc

    @app.exception_handler(RequestValidationError)
    async def _validation_error(_request: Request, exc: RequestValidationError) -> JSONResponse:
        errors = _json_safe(jsonable_encoder(exc.errors()))
        return JSONResponse({"detail": errors, "code": "validation_error"}, status_code=422)
