"""Measurement writes per second through the API against raw SQLAlchemy on the same file.

API: sequential ``POST /api/trials/{id}/measurements`` (one repeat each, fresh
Idempotency-Key) from one keep-alive client, spread over a set of trials, through auth,
validation, idempotency check, objective/SEM update, audit row, version bump and the
receipt (the repeats stored, the trial's new objective). Raw:
``session.add(Measurement(...)); session.commit()`` per row through ``app.db.make_engine``
with the same pragmas (WAL, ``--synchronous`` FULL by default, as the server) on the same
database file, same trials. Also timed: the service function alone (no HTTP), the same
posts from ``http.client`` (the server's rate without httpx's own per-request cost) and
``GET /health`` from HandfulClient (the HTTP floor of any call), and the API's throughput
with ``--clients`` HandfulClients posting at once (a lab's workers and operator: the server
works on one post while the others are on the wire). Rounds rotate the order; the ratios
are medians of each round's ratio to its own raw run.

    python benchmarks/service_measurements.py [--writes 300] [--rounds 3] [--clients 4]
        [--synchronous FULL|NORMAL]
"""

from __future__ import annotations

import argparse
import http.client
import json
import statistics
import sys
import tempfile
import time
import uuid
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from service_common import bench_server, run_in_threads
from tqdm import tqdm

from app.client import HandfulClient
from app.db.base import utcnow
from app.db.models import Measurement
from app.db.session import make_engine, make_sessionmaker


def api_round(url: str, token: str, trial_ids: list[int], writes: int, clients: int) -> float:
    """Writes/s of ``writes`` measurement posts split over ``clients`` threads, each with its
    own keep-alive HandfulClient (connected before the clock starts)."""
    per = writes // clients
    conns = [HandfulClient(url, token) for _ in range(clients)]
    for c in conns:
        c.request("GET", "/health")  # open the connection

    def work(k: int) -> None:
        for i in range(per):
            conns[k].add_measurements(
                trial_ids[(k * per + i) % len(trial_ids)],
                [{"value": 2.0 + 0.001 * i, "unit": "m/s"}],
                idempotency_key=uuid.uuid4().hex,
            )

    try:
        rate = per * clients / run_in_threads(clients, work)
    finally:
        for c in conns:
            c.close()
    return rate


def floor_round(url: str, token: str, n: int) -> float:
    """Round trips/s of ``GET /health`` (HTTP, auth-free, one read transaction) from the same
    client: the most any API call can reach on this machine, whatever the route does."""
    with HandfulClient(url, token) as c:
        t0 = time.perf_counter()
        for _ in range(n):
            c.request("GET", "/health")
        return n / (time.perf_counter() - t0)


def raw_round(db_url: str, trial_ids: list[int], writes: int, synchronous: str) -> float:
    """Writes/s of ORM insert + commit, one row per transaction."""
    engine = make_engine(db_url, sqlite_synchronous=synchronous)
    maker = make_sessionmaker(engine)
    t0 = time.perf_counter()
    with maker() as s:
        for i in range(writes):
            s.add(
                Measurement(
                    trial_id=trial_ids[i % len(trial_ids)],
                    value=2.0 + 0.001 * i,
                    unit="m/s",
                    note="",
                    source="tape",
                    created_by="bench",
                    created_at=utcnow(),
                )
            )
            s.commit()
    rate = writes / (time.perf_counter() - t0)
    engine.dispose()
    return rate


def service_round(db_url: str, trial_ids: list[int], writes: int, synchronous: str) -> float:
    """Writes/s of the service function alone (no HTTP): validation, idempotency, objective,
    audit, version, reply built; on the same file. Where the API's time goes."""
    from app.db.session import Database
    from app.service.auth import Actor
    from app.service.measurements import add_measurements
    from app.service.schemas import MeasurementsIn

    db = Database(db_url, sqlite_synchronous=synchronous)
    actor = Actor("bench", "operator")
    t0 = time.perf_counter()
    for i in range(writes):
        body = MeasurementsIn(repeats=[{"value": 2.0 + 0.001 * i, "unit": "m/s"}])
        with db.write() as s:
            add_measurements(
                s,
                trial_ids[i % len(trial_ids)],
                body,
                idempotency_key=uuid.uuid4().hex,
                actor=actor,
            )
    rate = writes / (time.perf_counter() - t0)
    db.dispose()
    return rate


def lean_round(url: str, token: str, trial_ids: list[int], writes: int) -> float:
    """Writes/s of the same posts from the standard library's ``http.client`` on one
    keep-alive connection: the server's own rate, without httpx's per-request cost."""
    host, port = url.removeprefix("http://").split(":")
    conn = http.client.HTTPConnection(host, int(port), timeout=600)
    headers = {"Authorization": f"Bearer {token}", "Content-Type": "application/json"}
    t0 = time.perf_counter()
    for i in range(writes):
        body = json.dumps({"repeats": [{"value": 2.0 + 0.001 * i, "unit": "m/s"}]})
        path = f"/api/trials/{trial_ids[i % len(trial_ids)]}/measurements"
        conn.request("POST", path, body, {**headers, "Idempotency-Key": uuid.uuid4().hex})
        reply = conn.getresponse()
        data = reply.read()
        if reply.status != 201:
            raise RuntimeError(f"HTTP {reply.status}: {data[:200]!r}")
        json.loads(data)
    rate = writes / (time.perf_counter() - t0)
    conn.close()
    return rate


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--writes", type=int, default=300)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--clients", type=int, default=4)
    ap.add_argument("--trials", type=int, default=100)
    ap.add_argument("--synchronous", choices=("FULL", "NORMAL"), default="FULL")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    names = ("raw", "api", "lean", "concurrent", "service", "health")
    rounds: dict[str, list[float]] = {k: [] for k in names}
    with (
        tempfile.TemporaryDirectory() as tmp,
        bench_server(Path(tmp), env={"HANDFUL_SQLITE_SYNCHRONOUS": args.synchronous}) as srv,
    ):
        api = HandfulClient(srv.url, srv.token, timeout=600)
        exp = api.create_experiment(name="writes", task="tip_speed", levels=3, method="random")
        trial_ids: list[int] = []
        while len(trial_ids) < args.trials:
            trial_ids += [t["id"] for t in api.suggest(exp["id"], n=100)]
        trial_ids = trial_ids[: args.trials]
        api_round(srv.url, srv.token, trial_ids, 20, 1)  # warm-up
        runs = {
            "raw": lambda: raw_round(srv.db_url, trial_ids, args.writes, args.synchronous),
            "api": lambda: api_round(srv.url, srv.token, trial_ids, args.writes, 1),
            "lean": lambda: lean_round(srv.url, srv.token, trial_ids, args.writes),
            "concurrent": lambda: api_round(
                srv.url, srv.token, trial_ids, args.writes, args.clients
            ),
            "service": lambda: service_round(srv.db_url, trial_ids, args.writes, args.synchronous),
            "health": lambda: floor_round(srv.url, srv.token, args.writes),
        }
        for k in tqdm(range(args.rounds), desc="rounds", unit="round"):
            names = list(runs)
            for name in names[k % len(names) :] + names[: k % len(names)]:  # rotate the order
                rounds[name].append(runs[name]())
        api.close()
    med = {k: statistics.median(v) for k, v in rounds.items()}
    # each round's ratio to that round's raw run (minutes apart at most), then their median:
    # this VM's speed drifts by tens of percent between rounds
    ratios = {k: [x / y for x, y in zip(v, rounds["raw"], strict=True)] for k, v in rounds.items()}
    ratio = {k: statistics.median(v) for k, v in ratios.items()}
    what = {
        "raw": "raw SQLAlchemy insert + commit",
        "api": "API, HandfulClient (httpx), 1 client",
        "lean": "API, http.client (1 connection)",
        "concurrent": f"API, {args.clients} HandfulClients at once",
        "service": "service function alone (no HTTP)",
        "health": "GET /health from HandfulClient",
    }
    print(f"synchronous={args.synchronous}, {args.writes} writes x {args.rounds} rounds (medians)")
    print(f"  {'':44s} {'per s':>9s} {'ms each':>8s} {'/ raw':>7s}  per round / raw")
    for k in names:
        spread = f"{min(ratios[k]):.3f}-{max(ratios[k]):.3f}"
        print(f"  {what[k]:44s} {med[k]:9.1f} {1e3 / med[k]:8.2f} {ratio[k]:7.3f}  {spread}")
    print("  rounds:", {k: [round(x, 1) for x in v] for k, v in rounds.items()})
    if args.json:
        args.json.write_text(
            json.dumps(
                {
                    "per_s": med,
                    "ratio": ratio,
                    "ratios": ratios,
                    "rounds": rounds,
                    "clients": args.clients,
                    "synchronous": args.synchronous,
                    "writes": args.writes,
                }
            )
        )


if __name__ == "__main__":
    main()
