"""Pool processes do not outlive a parent killed with SIGKILL (a sweep or worker killed)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

PARENT = """
import os, sys, time
from app.procs import process_pool

if __name__ == "__main__":
    with process_pool(2) as ex:
        # both processes busy, as in a sweep: each reports its pid, then works on
        started = [ex.submit(time.sleep, 0.5) for _ in range(2)]
        pids = {ex.submit(os.getpid).result() for _ in range(20)}
        for f in started:
            f.result()
        for _ in range(2):
            ex.submit(time.sleep, 300)
        print(" ".join(map(str, sorted(pids))), flush=True)
        time.sleep(300)
"""


def _alive(pid: int) -> bool:
    """Running (a zombie waiting for a reaper counts as gone)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except FileNotFoundError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"


def test_pool_processes_exit_when_their_parent_is_killed(tmp_path):
    parent = subprocess.Popen(
        [sys.executable, "-c", PARENT], stdout=subprocess.PIPE, text=True, cwd=tmp_path
    )
    try:
        line = parent.stdout.readline()
        pids = [int(p) for p in line.split()]
        assert pids and all(_alive(p) for p in pids), line
    finally:
        parent.send_signal(signal.SIGKILL)
        parent.wait(timeout=30)
    deadline = time.monotonic() + 15
    while any(_alive(p) for p in pids) and time.monotonic() < deadline:
        time.sleep(0.1)
    left = [p for p in pids if _alive(p)]
    for p in left:  # do not leave them behind if the test fails
        os.kill(p, signal.SIGKILL)
    assert left == [], f"pool processes outlived their parent: {left}"
