"""handful's server in a subprocess on 127.0.0.1: start it, wait for /health, stop or kill it.

One way to do this for the demo, the tests and the benchmarks::

    srv = ServerProcess(data_dir, free_port(), env={"HANDFUL_DASHBOARD_ENABLED": "0"})
    srv.start()          # returns once GET /health answers 200
    ...
    srv.stop()           # SIGTERM, then SIGKILL after 15 s; kill9() for a crash
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import httpx

REPO = Path(__file__).resolve().parents[1]


def free_port() -> int:
    """A TCP port free on 127.0.0.1 right now."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def wait_healthy(
    url: str, proc: subprocess.Popen[bytes], timeout_s: float, *, log_path: Path | None = None
) -> None:
    """Return once ``url``/health answers 200; RuntimeError (with the log's tail) if ``proc``
    exits first or ``timeout_s`` passes."""

    def tail() -> str:
        if log_path is None:
            return ""
        with contextlib.suppress(OSError):
            return ":\n" + log_path.read_text(errors="replace")[-4000:]
        return ""

    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"the server exited with {proc.returncode} during start-up{tail()}")
        with contextlib.suppress(httpx.HTTPError):
            if httpx.get(f"{url}/health", timeout=2.0).status_code == 200:
                return
        time.sleep(0.1)
    raise RuntimeError(f"the server did not answer /health within {timeout_s:.0f} s{tail()}")


@dataclass
class ServerProcess:
    """uvicorn serving ``app.api.main:create_app`` (or ``handful serve`` with ``use_cli``)
    over ``data_dir`` on 127.0.0.1:``port``; ``env`` is added to this process's environment.
    Output goes to ``data_dir/server.log``."""

    data_dir: Path
    port: int
    env: dict[str, str] = field(default_factory=dict)
    use_cli: bool = False
    proc: subprocess.Popen[bytes] | None = None
    log_path: Path = field(init=False)

    def __post_init__(self) -> None:
        self.log_path = self.data_dir / "server.log"

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def command(self) -> list[str]:
        common = ["--host", "127.0.0.1", "--port", str(self.port), "--log-level", "warning"]
        if self.use_cli:
            return [sys.executable, "-m", "app.cli", "serve", *common]
        return [sys.executable, "-m", "uvicorn", "--factory", "app.api.main:create_app", *common]

    def start(self, timeout_s: float = 90.0) -> None:
        """Start (or restart) the server and wait until /health answers."""
        assert self.proc is None or self.proc.poll() is not None, "already running"
        self.data_dir.mkdir(parents=True, exist_ok=True)
        env = {**os.environ, **self.env, "HANDFUL_DATA_DIR": str(self.data_dir)}
        log = open(self.log_path, "ab")  # noqa: SIM115 (the child owns it)
        self.proc = subprocess.Popen(
            self.command(), cwd=REPO, env=env, stdout=log, stderr=subprocess.STDOUT
        )
        log.close()
        try:
            wait_healthy(self.url, self.proc, timeout_s, log_path=self.log_path)
        except RuntimeError:
            self.stop(kill=True)
            raise

    def kill9(self) -> None:
        """SIGKILL the server (no shutdown hooks, no flushing) and reap it."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGKILL)
            self.proc.wait(timeout=30)

    def stop(self, kill: bool = False) -> None:
        """Stop the server (SIGTERM, then SIGKILL after 15 s)."""
        if self.proc is None or self.proc.poll() is not None:
            return
        if kill:
            self.kill9()
            return
        self.proc.terminate()
        try:
            self.proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            self.kill9()

    def log_tail(self, n: int = 4000) -> str:
        try:
            return self.log_path.read_text(errors="replace")[-n:]
        except OSError:
            return ""
