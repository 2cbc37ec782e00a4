"""Fixtures for the dashboard's browser tests: a real server process and headless Chromium.

The server is uvicorn in a subprocess over a SQLite file built by the Alembic migrations, with
its viser 3D server on its own free port; both listen on 127.0.0.1 only.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import httpx
import pytest

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]
PASSWORDS = {"olga": "operator-pass-1", "victor": "viewer-pass-1"}
SCREENSHOTS = Path(__file__).resolve().parents[2] / "test-output" / "screenshots"


def free_port() -> int:
    """A TCP port free on 127.0.0.1 right now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@dataclass
class LiveServer:
    """A running server: its base URL, its viser port, tokens by role, its data folder."""

    url: str
    viser_port: int
    data_dir: Path
    tokens: dict[str, str]
    process: subprocess.Popen[bytes]
    log_path: Path

    def client(self, role: str = "operator") -> httpx.Client:
        """An httpx client with that role's token."""
        return httpx.Client(
            base_url=self.url,
            headers={"Authorization": f"Bearer {self.tokens[role]}"},
            timeout=30.0,
        )

    def log(self) -> str:
        """The server's output so far (for failure messages)."""
        return self.log_path.read_text(errors="replace")[-4000:]


def _seed_users(db_url: str) -> dict[str, str]:
    from app.db.session import Database
    from app.service.auth import add_user, create_token

    db = Database(db_url)
    tokens: dict[str, str] = {}
    try:
        with db.write() as s:
            add_user(s, "olga", "operator", password=PASSWORDS["olga"])
            add_user(s, "victor", "viewer", password=PASSWORDS["victor"])
            add_user(s, "wanda", "worker")
            tokens["operator"] = create_token(s, "olga", label="tests")
            tokens["viewer"] = create_token(s, "victor", label="tests")
            tokens["worker"] = create_token(s, "wanda", label="tests")
    finally:
        db.dispose()
    return tokens


@pytest.fixture(scope="module")
def live_server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LiveServer]:
    """uvicorn on a free loopback port over a freshly migrated SQLite file."""
    from app.db.migrate import upgrade

    data_dir = tmp_path_factory.mktemp("handful-data")
    db_url = f"sqlite:///{data_dir / 'handful.db'}"
    upgrade(db_url)
    tokens = _seed_users(db_url)
    port, viser_port = free_port(), free_port()
    env = {
        **os.environ,
        "HANDFUL_DATA_DIR": str(data_dir),
        "HANDFUL_HOST": "127.0.0.1",
        "HANDFUL_PORT": str(port),
        "HANDFUL_VISER_PORT": str(viser_port),
        "HANDFUL_DASHBOARD_ENABLED": "true",
        "PYTHONUNBUFFERED": "1",
    }
    log_path = data_dir / "server.log"
    with log_path.open("wb") as log:
        process = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "uvicorn",
                "--factory",
                "app.api.main:create_app",
                "--host",
                "127.0.0.1",
                "--port",
                str(port),
                "--log-level",
                "warning",
            ],
            env=env,
            stdout=log,
            stderr=subprocess.STDOUT,
        )
    server = LiveServer(f"http://127.0.0.1:{port}", viser_port, data_dir, tokens, process, log_path)
    try:
        deadline = time.monotonic() + 60.0
        while True:
            if process.poll() is not None:
                raise RuntimeError(f"server exited with {process.returncode}:\n{server.log()}")
            try:
                if httpx.get(f"{server.url}/viz/status", timeout=1.0).json().get("running"):
                    break
            except (httpx.HTTPError, ValueError):
                pass
            if time.monotonic() > deadline:
                raise RuntimeError(f"server did not come up in 60 s:\n{server.log()}")
            time.sleep(0.2)
        server.viser_port = int(httpx.get(f"{server.url}/viz/status").json()["port"])
        yield server
    finally:
        process.terminate()
        try:
            process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


@pytest.fixture(scope="module")
def browser() -> Iterator[object]:
    """Headless Debian Chromium driven by Playwright."""
    from playwright.sync_api import sync_playwright

    if not Path(CHROMIUM).exists():
        raise RuntimeError(
            f"{CHROMIUM} is missing: apt-get install -y chromium (scripts/dev.sh does it)"
        )
    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        try:
            yield b
        finally:
            b.close()


@pytest.fixture(scope="session")
def screenshots() -> Path:
    """Folder for page screenshots (look at them)."""
    SCREENSHOTS.mkdir(parents=True, exist_ok=True)
    return SCREENSHOTS
