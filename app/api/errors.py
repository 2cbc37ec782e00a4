"""Errors → HTTP, in one place: domain errors as ``{"detail": "<words>", "code": "<kind>"}``;
request validation errors in FastAPI's list form (``loc``, ``msg``), made JSON-safe and cut
short (at most ``MAX_ERRORS`` entries, inputs shortened). ``ERROR_RESPONSES`` declares every
error reply in the OpenAPI document, with its schema."""

from __future__ import annotations

import math
from typing import Any

from fastapi import FastAPI, Request
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import BaseModel, ConfigDict, Field
from sqlalchemy.exc import OperationalError
from sqlalchemy.exc import TimeoutError as PoolTimeout
from starlette.exceptions import HTTPException as StarletteHTTPException

from app.service.errors import DuplicateRequest, IllegalTransition, ServiceError


class ErrorRead(BaseModel):
    """A refused request: what is wrong, in words, and its kind."""

    model_config = ConfigDict(extra="forbid")

    detail: str
    code: str = Field(description="not_found, illegal_transition, conflict, unauthorized, ...")
    current_status: str | None = Field(None, description="illegal_transition: the trial's state")
    receipt: dict[str, Any] | None = Field(
        None, description="duplicate_request: the first request's reply"
    )


class ValidationIssue(BaseModel):
    """One reason a request was refused by validation (FastAPI's form)."""

    loc: list[str | int]
    msg: str
    type: str
    input: Any = None
    ctx: dict[str, Any] | None = None


class ValidationErrorRead(BaseModel):
    """422: the request's shape (``detail`` a list, ``code`` validation_error) or its content
    (``detail`` words, ``code`` invalid_input or safety_violation) is wrong."""

    detail: list[ValidationIssue] | str
    code: str


def _error(description: str, model: type[BaseModel] = ErrorRead) -> dict[str, Any]:
    return {"description": description, "model": model}


#: every error reply an /api operation may give (declared on each; schemathesis holds us to it)
ERROR_RESPONSES: dict[int | str, dict[str, Any]] = {
    400: _error("The body could not be read (not UTF-8 JSON)"),
    401: _error("No token, or an unknown, expired or revoked one"),
    403: _error("This role may not do this"),
    404: _error("No such experiment, trial, lease or preview"),
    409: _error("The request conflicts with the current state (illegal_transition, ...)"),
    413: _error("The request body or an uploaded trajectory is too large"),
    422: _error(
        "Invalid input (validation_error, invalid_input, safety_violation)", ValidationErrorRead
    ),
    429: _error("Too many attempts; retry after Retry-After seconds"),
    503: _error("The database is busy or a computation ran out of time; retry after Retry-After"),
}

MAX_ERRORS = 20  # validation issues echoed back at most
MAX_INPUT_CHARS = 200  # an echoed input longer than this is cut


def _short(issue: dict[str, Any]) -> dict[str, Any]:
    out = {k: issue[k] for k in ("loc", "msg", "type", "ctx") if k in issue}
    if "input" in issue:
        text = repr(issue["input"]) if not isinstance(issue["input"], str) else issue["input"]
        if len(text) > MAX_INPUT_CHARS or not isinstance(
            issue["input"], str | int | float | bool | type(None)
        ):
            out["input"] = text[:MAX_INPUT_CHARS] + ("…" if len(text) > MAX_INPUT_CHARS else "")
        else:
            out["input"] = issue["input"]
    if isinstance(out.get("msg"), str) and len(out["msg"]) > 1000:
        out["msg"] = out["msg"][:1000] + "…"
    return out


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
        if exc.status_code in (429, 503):
            headers = {"Retry-After": str(getattr(exc, "retry_after_s", 1))}
        return JSONResponse(body, status_code=exc.status_code, headers=headers)

    @app.exception_handler(StarletteHTTPException)
    async def _http_error(_request: Request, exc: StarletteHTTPException) -> JSONResponse:
        codes = {400: "bad_request", 404: "not_found", 405: "method_not_allowed"}
        body = {"detail": str(exc.detail), "code": codes.get(exc.status_code, "http_error")}
        return JSONResponse(body, status_code=exc.status_code, headers=exc.headers)

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
        issues = list(exc.errors())
        errors = [_short(e) for e in issues[:MAX_ERRORS]]
        if len(issues) > MAX_ERRORS:
            errors.append(
                {
                    "loc": ["body"],
                    "msg": f"… and {len(issues) - MAX_ERRORS} more problems",
                    "type": "truncated",
                }
            )
        body = _json_safe(jsonable_encoder(errors))
        return JSONResponse({"detail": body, "code": "validation_error"}, status_code=422)
