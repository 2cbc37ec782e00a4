"""The load run of issue 16: N clients for T seconds against a real server, then /health while
another program holds SQLite's write lock.

    python benchmarks/load_run.py --clients 8 --seconds 60 --lock-seconds 30

Phase 1: each client (its own HandfulClient, its own trial) posts one measurement after
another (every 5th request a GET of its trial instead) for ``--seconds``; every reply must be
a success. Phase 2: another process takes SQLite's write lock (BEGIN IMMEDIATE) for
``--lock-seconds``; meanwhile the clients keep posting (HandfulClient waits out the 503
database_busy replies, honouring Retry-After, within its deadline) and one more client polls
GET /health every 50 ms. Prints one JSON object (latencies in ms) and a Markdown table.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from app.client import HandfulAPIError, HandfulClient
from benchmarks.service_common import bench_server

HOLD = """
import sqlite3, sys, time
c = sqlite3.connect(sys.argv[1], isolation_level=None)
c.execute("BEGIN IMMEDIATE")
print("locked", flush=True)
time.sleep(float(sys.argv[2]))
c.rollback()
"""


def _pct(values: list[float]) -> dict[str, float]:
    if not values:
        return {"n": 0}
    a = np.asarray(values) * 1e3
    return {
        "n": len(values),
        "p50_ms": round(float(np.percentile(a, 50)), 2),
        "p99_ms": round(float(np.percentile(a, 99)), 2),
        "max_ms": round(float(a.max()), 2),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--clients", type=int, default=8)
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--lock-seconds", type=float, default=30.0)
    args = ap.parse_args()

    with tempfile.TemporaryDirectory() as tmp, bench_server(Path(tmp) / "data") as srv:
        setup = HandfulClient(srv.url, srv.token, timeout=120)
        exp = setup.create_experiment(name="load", task="tip_speed", levels=3, method="random")
        trial_ids = [t["id"] for t in setup.suggest(exp["id"], n=args.clients)]
        posts: list[list[float]] = [[] for _ in range(args.clients)]
        gets: list[list[float]] = [[] for _ in range(args.clients)]
        errors: list[str] = []
        phase = {"name": "load"}
        locked_posts: list[float] = []
        stop = threading.Event()

        def client(k: int) -> None:
            with HandfulClient(srv.url, srv.token, timeout=120, busy_deadline_s=120) as c:
                i = 0
                while not stop.is_set():
                    i += 1
                    t0 = time.perf_counter()
                    try:
                        if i % 5 == 0:
                            c.get_trial(trial_ids[k])
                            gets[k].append(time.perf_counter() - t0)
                        else:
                            c.add_measurements(trial_ids[k], [{"value": 1.0, "unit": "m/s"}])
                            dt = time.perf_counter() - t0
                            (locked_posts if phase["name"] == "locked" else posts[k]).append(dt)
                    except (HandfulAPIError, OSError) as exc:
                        errors.append(f"{type(exc).__name__}: {exc}")

        threads = [threading.Thread(target=client, args=(k,)) for k in range(args.clients)]
        t_start = time.perf_counter()
        for t in threads:
            t.start()
        time.sleep(args.seconds)
        load_s = time.perf_counter() - t_start
        # phase 2: another program holds the write lock
        phase["name"] = "locked"
        holder = subprocess.Popen(
            [
                sys.executable,
                "-c",
                HOLD,
                str(Path(tmp) / "data" / "handful.db"),
                str(args.lock_seconds),
            ],
            stdout=subprocess.PIPE,
            text=True,
        )
        assert holder.stdout is not None and holder.stdout.readline().strip() == "locked"
        health: list[float] = []
        health_errors = 0
        with HandfulClient(srv.url, None, timeout=120) as h:
            t_lock = time.perf_counter()
            while holder.poll() is None:
                t0 = time.perf_counter()
                try:
                    h.health()
                except (HandfulAPIError, OSError):
                    health_errors += 1
                health.append(time.perf_counter() - t0)
                time.sleep(0.05)
            lock_s = time.perf_counter() - t_lock
        time.sleep(2.0)  # let the waiting posts through
        stop.set()
        for t in threads:
            t.join()
        all_posts = [x for p in posts for x in p]
        out = {
            "clients": args.clients,
            "load_seconds": round(load_s, 1),
            "errors": len(errors),
            "error_samples": errors[:5],
            "measurement_posts": _pct(all_posts),
            "posts_per_s": round(len(all_posts) / load_s, 1),
            "trial_gets": _pct([x for g in gets for x in g]),
            "lock_seconds": round(lock_s, 1),
            "health_while_locked": {**_pct(health), "errors": health_errors},
            "posts_that_waited_out_the_lock": _pct(locked_posts),
            "cpus": os.cpu_count(),
            "loadavg": [round(v, 1) for v in os.getloadavg()],
        }
    print(json.dumps(out, indent=1))
    mp, hw = out["measurement_posts"], out["health_while_locked"]
    print(
        f"\n| clients | s | errors | posts | posts/s | post p50 | post p99 | "
        f"/health p50 (locked) | /health p99 (locked) | /health max |\n"
        f"|---|---|---|---|---|---|---|---|---|---|\n"
        f"| {args.clients} | {out['load_seconds']} | {out['errors']} | {mp['n']} | "
        f"{out['posts_per_s']} | {mp['p50_ms']} ms | {mp['p99_ms']} ms | {hw['p50_ms']} ms | "
        f"{hw['p99_ms']} ms | {hw['max_ms']} ms |"
    )


if __name__ == "__main__":
    main()
