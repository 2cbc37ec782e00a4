"""Domain errors → HTTP, in one place: ``{"detail": "<words>", "code": "<kind>"}``."""

from __future__ import annotations

from typing import Any

from fastapi import FastAPI, Request
from fastapi.responses import JSONResponse

from app.service.errors import IllegalTransition, ServiceError


def install(app: FastAPI) -> None:
    """Register the ServiceError handler on ``app``."""

    @app.exception_handler(ServiceError)
    async def _service_error(_request: Request, exc: ServiceError) -> JSONResponse:
        body: dict[str, Any] = {"detail": str(exc), "code": exc.code}
        if isinstance(exc, IllegalTransition):
            body["current_status"] = exc.current
        headers = {"WWW-Authenticate": "Bearer"} if exc.status_code == 401 else None
        return JSONResponse(body, status_code=exc.status_code, headers=headers)
