"""Fixtures for the dashboard's browser tests: a dashboard server and headless Chromium.

The server comes from the shared ``server_factory`` (uvicorn subprocess over a migrated SQLite
file, users ``operator``/``viewer``/``worker``), with the dashboard on and its viser 3D server
on a free 127.0.0.1 port.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from app.devserver import free_port

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]
SCREENSHOTS = Path(__file__).resolve().parents[2] / "test-output" / "screenshots"


@pytest.fixture
def dashboard_server_factory(server_factory: Callable[..., Any]) -> Callable[..., Any]:
    """Start servers with the dashboard mounted and viser on a free loopback port."""

    def start(**env: str) -> Any:
        return server_factory(dashboard=True, env={"HANDFUL_VISER_PORT": str(free_port()), **env})

    return start


@pytest.fixture
def dashboard_server(dashboard_server_factory: Callable[..., Any]) -> Any:
    """A server with the dashboard mounted and viser on its own free loopback port."""
    return dashboard_server_factory()


@pytest.fixture(scope="session")
def browser() -> Iterator[Any]:
    """Headless Debian Chromium driven by Playwright (no browser download)."""
    from playwright.sync_api import sync_playwright

    if not Path(CHROMIUM).exists():
        raise RuntimeError(f"{CHROMIUM} is missing: apt-get install -y chromium (scripts/dev.sh)")
    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            yield b
        finally:
            b.close()


@pytest.fixture
def page(browser: Any) -> Iterator[Any]:
    """A fresh 1280×800 tab (own storage); page errors fail the test at teardown."""
    context = browser.new_context(viewport={"width": 1280, "height": 800})
    tab = context.new_page()
    errors: list[str] = []
    tab.on("pageerror", lambda exc: errors.append(str(exc)))
    tab.set_default_timeout(60_000)  # a loaded 2-core CI machine renders slowly
    yield tab
    context.close()
    assert not errors, f"JavaScript errors on the page: {errors}"


@pytest.fixture(scope="session")
def screenshots() -> Path:
    """Where page screenshots go (look at them: passing is not looking right)."""
    SCREENSHOTS.mkdir(parents=True, exist_ok=True)
    return SCREENSHOTS
