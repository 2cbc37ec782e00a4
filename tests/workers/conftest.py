"""Worker processes for the end-to-end tests: real `handful worker ...` subprocesses.

``worker_factory(server, kind, *args)`` starts ``python -m app.cli worker KIND`` against a
`ServerHandle` (from tests/conftest.py) in its own process group, logging to a file; the handle
can ``kill9()`` the whole group (the worker and its pool processes, like a machine dying),
``terminate()`` it (SIGTERM, clean exit), and list the trials it ran from its log.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

REPO = Path(__file__).resolve().parents[2]
RAN = re.compile(r"ran trial (\d+) lease (\S+)")


@dataclass
class WorkerProc:
    """One worker subprocess (a process-group leader)."""

    proc: subprocess.Popen[bytes]
    log_path: Path

    def log(self) -> str:
        """Everything the worker wrote so far."""
        return self.log_path.read_text(errors="replace")

    def ran(self) -> list[int]:
        """Trial ids this worker finished running (from its log), in order."""
        return [int(m.group(1)) for m in RAN.finditer(self.log())]

    def kill9(self) -> None:
        """SIGKILL the worker and every process it started."""
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait(timeout=30)

    def terminate(self, timeout_s: float = 60.0) -> int:
        """SIGTERM (finish in-flight trials, then exit); return the exit code."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        return self.proc.wait(timeout=timeout_s)

    def wait(self, timeout_s: float = 120.0) -> int:
        """Wait for the worker to exit on its own; return its exit code."""
        return self.proc.wait(timeout=timeout_s)


@pytest.fixture
def worker_factory(tmp_path: Path) -> Iterator[Callable[..., WorkerProc]]:
    """Start `handful worker KIND` processes; every one is killed at teardown."""
    procs: list[WorkerProc] = []

    def start(server: Any, kind: str, *args: str, role: str = "worker") -> WorkerProc:
        log_path = tmp_path / f"worker{len(procs)}-{kind}.log"
        token_file = tmp_path / f"worker{len(procs)}.token"
        token_file.write_text(server.tokens[role] + "\n")
        token_file.chmod(0o600)
        cmd = [
            sys.executable,
            "-m",
            "app.cli",
            "worker",
            kind,
            "--server",
            server.url,
            "--token-file",  # never on the command line (ps shows it to everyone)
            str(token_file),
            "--poll",
            "0.2",
            *args,
        ]
        with open(log_path, "wb") as log:
            proc = subprocess.Popen(
                cmd,
                cwd=REPO,
                stdout=log,
                stderr=subprocess.STDOUT,
                start_new_session=True,
                env={**os.environ, "PYTHONUNBUFFERED": "1"},
            )
        handle = WorkerProc(proc, log_path)
        procs.append(handle)
        return handle

    yield start
    for p in procs:
        p.kill9()


def wait_for(
    what: str, predicate: Callable[[], Any], *, timeout_s: float = 120.0, poll_s: float = 0.1
) -> Any:
    """Poll until `predicate()` is truthy; return it, or fail naming `what`."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")
        time.sleep(poll_s)


@pytest.fixture
def wait_until() -> Callable[..., Any]:
    """The `wait_for` poller, for tests (conftest modules are not importable)."""
    return wait_for
