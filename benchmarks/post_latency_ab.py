"""One client's measurement-post and /health latency against the server of a source tree,
for A/B runs of two trees alternated in one shell loop (each run its own fresh server):

    for r in /work/main /work/wt/harden /work/main /work/wt/harden; do
        PYTHONPATH=$r python benchmarks/post_latency_ab.py $r 15; done
"""

from __future__ import annotations

import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import httpx


def main(root: str, seconds: float) -> None:
    sys.path.insert(0, root)
    os.chdir(root)
    from benchmarks.service_common import bench_server  # the tree given

    with tempfile.TemporaryDirectory() as tmp, bench_server(Path(tmp) / "data") as srv:
        c = httpx.Client(
            base_url=srv.url, headers={"Authorization": f"Bearer {srv.token}"}, timeout=60
        )
        spec = {"name": "ab", "task": "tip_speed", "levels": 3, "method": "random"}
        exp = c.post("/api/experiments", json=spec).json()
        tid = c.post(f"/api/experiments/{exp['id']}/suggest", json={"n": 1}).json()[0]["id"]
        posts: list[float] = []
        health: list[float] = []
        body = {"repeats": [{"value": 1.0, "unit": "m/s"}]}
        end = time.time() + seconds
        while time.time() < end:
            t0 = time.perf_counter()
            key = {"Idempotency-Key": f"k{len(posts)}"}
            r = c.post(f"/api/trials/{tid}/measurements", json=body, headers=key)
            assert r.status_code == 201, r.text
            posts.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            c.get("/health")
            health.append(time.perf_counter() - t0)
    print(
        f"{root} posts {len(posts)} p50 {1e3 * statistics.median(posts):.1f} ms "
        f"health p50 {1e3 * statistics.median(health):.1f} ms"
    )


if __name__ == "__main__":
    main(sys.argv[1], float(sys.argv[2]))
