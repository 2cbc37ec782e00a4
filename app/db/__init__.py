"""Persistence: SQLAlchemy 2 typed models, engine/session setup and Alembic migrations."""

from app.db.base import Base
from app.db.session import Database, make_engine, make_sessionmaker

__all__ = ["Base", "Database", "make_engine", "make_sessionmaker"]
