"""`handful bench sim` (being built)."""

from __future__ import annotations

import typer


def register(bench_app: typer.Typer) -> None:
    """Add this benchmark to the `bench` group."""
