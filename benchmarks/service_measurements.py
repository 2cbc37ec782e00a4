"""Measurement writes per second through the API against raw SQLAlchemy on the same file.

API: sequential ``POST /api/trials/{id}/measurements`` (one repeat each, fresh
Idempotency-Key) from one keep-alive client, spread over a set of trials, through auth,
validation, idempotency check, objective/SEM update, audit row, version bump and a reply
with the trial and its repeats. Raw: ``session.add(Measurement(...)); session.commit()``
per row through ``app.db.make_engine`` with the same pragmas (WAL, ``--synchronous`` FULL
by default, as the server) on the same database file, same trials. Also timed: the
service function alone (no HTTP) and ``GET /health`` from the same client (the HTTP floor
of any call). Alternating rounds; medians.

    python benchmarks/service_measurements.py [--writes 300] [--rounds 3] [--clients 1]
        [--synchronous FULL|NORMAL]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import threading
import time
import uuid
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from service_common import bench_server

from app.client import HandfulClient
from app.db.base import utcnow
from app.db.models import Measurement
from app.db.session import make_engine, make_sessionmaker


def api_round(url: str, token: str, trial_ids: list[int], writes: int, clients: int) -> float:
    """Writes/s of ``writes`` measurement posts split over ``clients`` threads."""
    per = writes // clients

    def work(k: int) -> None:
        with HandfulClient(url, token) as c:
            for i in range(per):
                tid = trial_ids[(k * per + i) % len(trial_ids)]
                c.add_measurements(
                    tid,
                    [{"value": 2.0 + 0.001 * i, "unit": "m/s"}],
                    idempotency_key=uuid.uuid4().hex,
                )

    threads = [threading.Thread(target=work, args=(k,)) for k in range(clients)]
    t0 = time.perf_counter()
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return per * clients / (time.perf_counter() - t0)


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
                    source="operator",
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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--writes", type=int, default=300)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--clients", type=int, default=1)
    ap.add_argument("--trials", type=int, default=100)
    ap.add_argument("--synchronous", choices=("FULL", "NORMAL"), default="FULL")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    with (
        tempfile.TemporaryDirectory() as tmp,
        bench_server(Path(tmp), env={"HANDFUL_SQLITE_SYNCHRONOUS": args.synchronous}) as srv,
    ):
        api = HandfulClient(srv.url, srv.token, timeout=600)
        exp = api.create_experiment(name="writes", task="tip_speed", levels=3, method="random")
        trial_ids = [t["id"] for t in api.suggest(exp["id"], n=100)][: args.trials]
        while len(trial_ids) < args.trials:
            trial_ids += [t["id"] for t in api.suggest(exp["id"], n=100)]
        trial_ids = trial_ids[: args.trials]
        api_round(srv.url, srv.token, trial_ids, 20, 1)  # warm-up
        api_rates, raw_rates, svc_rates, floor_rates = [], [], [], []
        for _ in range(args.rounds):
            svc_rates.append(service_round(srv.db_url, trial_ids, args.writes, args.synchronous))
            api_rates.append(api_round(srv.url, srv.token, trial_ids, args.writes, args.clients))
            raw_rates.append(raw_round(srv.db_url, trial_ids, args.writes, args.synchronous))
            floor_rates.append(floor_round(srv.url, srv.token, args.writes))
        api.close()
    a, r = statistics.median(api_rates), statistics.median(raw_rates)
    sv = statistics.median(svc_rates)
    fl = statistics.median(floor_rates)
    print(
        f"synchronous={args.synchronous}  API {a:8.1f} writes/s ({args.clients} client(s))   "
        f"raw {r:8.1f} writes/s   "
        f"API/raw {a / r:6.3f}   (service alone, no HTTP: {sv:.1f} writes/s = {sv / r:.3f} of raw)"
    )
    print(
        f"  per write: API {1e3 / a:.2f} ms, service alone {1e3 / sv:.2f} ms, raw {1e3 / r:.2f} ms;"
        f" GET /health round trip {1e3 / fl:.2f} ms (= {fl / r:.3f} of raw: the HTTP floor)"
    )
    print(
        "  rounds API:", [round(x, 1) for x in api_rates], " raw:", [round(x, 1) for x in raw_rates]
    )
    if args.json:
        args.json.write_text(
            json.dumps(
                {
                    "api_per_s": a,
                    "raw_per_s": r,
                    "ratio": a / r,
                    "api_rounds": api_rates,
                    "raw_rounds": raw_rates,
                    "service_per_s": sv,
                    "service_rounds": svc_rates,
                    "health_per_s": fl,
                    "health_rounds": floor_rates,
                    "clients": args.clients,
                    "synchronous": args.synchronous,
                    "writes": args.writes,
                }
            )
        )


if __name__ == "__main__":
    main()
