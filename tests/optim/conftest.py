"""The optimiser tests run their GP work on one thread, as the server and the sweep do."""

from __future__ import annotations

import pytest

from app.procs import set_torch_threads


@pytest.fixture(autouse=True, scope="session")
def _one_torch_thread() -> None:
    set_torch_threads(1)
