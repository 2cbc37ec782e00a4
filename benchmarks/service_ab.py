"""A/B the measurement post of two source trees: both servers up at once, blocks alternating.

Each tree (a checkout, e.g. ``git worktree add /tmp/before <commit>``) serves its own
migrated SQLite file from its own uvicorn process on loopback; blocks of ``--block``
measurement posts from ``http.client`` (one keep-alive connection, fresh Idempotency-Key,
one repeat) alternate between them, A first in even rounds and B first in odd ones. Reported:
median wall ms per post and median server CPU ms per post (user + system of the server
process, from /proc), and the median of the per-round B/A ratios, which is what to quote on
a machine whose speed drifts. Both files are migrated by *this* checkout's migrations: compare
trees at the same schema head.

    python benchmarks/service_ab.py TREE_A TREE_B [--rounds 12] [--block 250]
"""

from __future__ import annotations

import argparse
import http.client
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path

from service_common import seed_database
from tqdm import tqdm

from app.client import HandfulClient
from app.devserver import free_port, wait_healthy


@dataclass
class Side:
    tree: Path
    port: int
    token: str
    trial_ids: list[int]
    proc: subprocess.Popen[bytes]
    ms: list[float] = field(default_factory=list)
    cpu_ms: list[float] = field(default_factory=list)


def _cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def start(tree: Path) -> Side:
    """Migrate a fresh file, add an operator, serve ``tree``'s app on a free port."""
    data = Path(tempfile.mkdtemp(prefix="handful-ab-"))
    _, token = seed_database(data)
    port = free_port()
    env = {
        **os.environ,
        "PYTHONPATH": str(tree),  # python -m also puts the working folder first
        "HANDFUL_DATA_DIR": str(data),
        "HANDFUL_DASHBOARD_ENABLED": "0",
    }
    cmd = [sys.executable, "-m", "uvicorn", "--factory", "app.api.main:create_app"]
    cmd += ["--host", "127.0.0.1", "--port", str(port), "--log-level", "warning"]
    log = open(data / "server.log", "wb")  # noqa: SIM115 (the child owns it)
    proc = subprocess.Popen(cmd, cwd=tree, env=env, stdout=log, stderr=subprocess.STDOUT)
    log.close()
    wait_healthy(f"http://127.0.0.1:{port}", proc, 90.0, log_path=data / "server.log")
    with HandfulClient(f"http://127.0.0.1:{port}", token) as api:
        exp = api.create_experiment(name="ab", task="tip_speed", levels=3, method="random")
        trial_ids = [t["id"] for t in api.suggest(exp["id"], n=100)]
    return Side(tree, port, token, trial_ids, proc)


def block(side: Side, n: int) -> tuple[float, float]:
    """``n`` posts; (wall ms, server CPU ms) per post."""
    conn = http.client.HTTPConnection("127.0.0.1", side.port, timeout=600)
    headers = {"Authorization": f"Bearer {side.token}", "Content-Type": "application/json"}
    cpu0, t0 = _cpu_s(side.proc.pid), time.perf_counter()
    for i in range(n):
        body = json.dumps({"repeats": [{"value": 2.0 + 0.001 * i, "unit": "m/s"}]})
        tid = side.trial_ids[i % len(side.trial_ids)]
        key = {"Idempotency-Key": uuid.uuid4().hex}
        conn.request("POST", f"/api/trials/{tid}/measurements", body, {**headers, **key})
        reply = conn.getresponse()
        data = reply.read()
        if reply.status != 201:
            raise RuntimeError(f"{side.tree}: HTTP {reply.status}: {data[:200]!r}")
    wall = (time.perf_counter() - t0) / n * 1e3
    cpu = (_cpu_s(side.proc.pid) - cpu0) / n * 1e3
    conn.close()
    return wall, cpu


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("tree_a", type=Path)
    ap.add_argument("tree_b", type=Path)
    ap.add_argument("--rounds", type=int, default=12)
    ap.add_argument("--block", type=int, default=250)
    args = ap.parse_args()
    sides = [start(args.tree_a.resolve()), start(args.tree_b.resolve())]
    try:
        for side in sides:
            block(side, 100)  # warm-up
        for r in tqdm(range(args.rounds), desc="rounds", unit="round"):
            for side in sides if r % 2 == 0 else sides[::-1]:
                wall, cpu = block(side, args.block)
                side.ms.append(wall)
                side.cpu_ms.append(cpu)
    finally:
        for side in sides:
            side.proc.terminate()
            side.proc.wait(timeout=30)
    a, b = sides
    for name, side in (("A", a), ("B", b)):
        print(
            f"{name} {side.tree}: {statistics.median(side.ms):.3f} ms a post, "
            f"server CPU {statistics.median(side.cpu_ms):.3f} ms a post"
        )
    wall = [y / x for x, y in zip(a.ms, b.ms, strict=True)]
    cpu = [y / x for x, y in zip(a.cpu_ms, b.cpu_ms, strict=True) if x > 0]
    print(
        f"B/A per round: wall {statistics.median(wall):.3f} ({min(wall):.3f}-{max(wall):.3f}), "
        f"server CPU {statistics.median(cpu):.3f}"
    )


if __name__ == "__main__":
    main()
