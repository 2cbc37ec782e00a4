"""HTTP API: ``create_app(settings)`` builds the FastAPI app; routes are thin over app.service."""

from app.api.main import create_app

__all__ = ["create_app"]
