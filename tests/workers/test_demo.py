"""`handful demo` as a user runs it: three processes, two experiments, Ctrl-C stops all."""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from app.client import HandfulClient
from app.devserver import free_port

REPO = Path(__file__).resolve().parents[2]


@pytest.mark.slow
def test_demo_runs_both_experiments_and_stops_cleanly_on_ctrl_c(tmp_path, wait_until):
    port = free_port()
    data = tmp_path / "demo"
    out_path = tmp_path / "demo.out"
    with open(out_path, "wb") as out:
        proc = subprocess.Popen(
            [
                *(sys.executable, "-m", "app.cli", "demo", "--port", str(port)),
                *("--data-dir", str(data), "--auto-confirm", "--no-realtime"),
                *("--max-parallel", "1", "--exit-after", "600"),
            ],
            cwd=REPO,
            stdout=out,
            stderr=subprocess.STDOUT,
            env={**os.environ, "PYTHONUNBUFFERED": "1"},
        )
    try:
        text = wait_until(
            "the demo banner",
            lambda: "operator token" in (t := out_path.read_text()) and t,
            timeout_s=180,
        )
        assert f"http://127.0.0.1:{port}/experiments/" in text
        token = re.search(r"operator token (\S+)", text).group(1)
        assert re.search(r"login +demo-operator / \S+", text)
        with HandfulClient(f"http://127.0.0.1:{port}", token=token) as api:
            exps = {e["target"]: e for e in api.list_experiments()}
            assert exps["sim"]["task"] == "throw"
            assert exps["hardware"]["task"] == "tip_speed"
            assert exps["hardware"]["limits"]["max_step_pa"] == 30_000.0

            def both_ran() -> bool:
                return all(
                    any(t["status"] == "completed" for t in api.list_trials(e["id"]))
                    for e in exps.values()
                )

            wait_until("a completed sim and hardware trial", both_ran, timeout_s=240, poll_s=1)
        proc.send_signal(signal.SIGINT)  # Ctrl-C
        assert proc.wait(timeout=120) == 0, out_path.read_text()[-3000:]
    finally:
        if proc.poll() is None:
            proc.kill()
    assert "demo stopped cleanly" in out_path.read_text()
    logs = {p.stem: p.read_text() for p in (data / "logs").glob("*.log")}
    assert set(logs) == {"server", "sim-worker", "standin-worker"}
    assert "trial(s) run, exiting" in logs["sim-worker"]
    assert "trial(s) run, exiting" in logs["standin-worker"]
    assert "Application shutdown complete" in logs["server"]
    assert (data / "standin_state.json").exists()  # the stand-in's drift persists
    with pytest.raises(ConnectionRefusedError):  # the server is gone
        socket.create_connection(("127.0.0.1", port), timeout=5).close()
