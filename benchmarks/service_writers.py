"""Concurrent writers in one process: the writer queue against SQLite's busy handler.

``--threads`` threads post measurements (``add_measurements``, in-process, no HTTP) over 100
queued trials through one ``Database``: as configured (SQLite writers queue for a single write
connection), and with the write sessions on the shared pool instead, each ``BEGIN
IMMEDIATE`` waiting in SQLite's busy handler (the configuration before the queue). Rounds
alternate the two; medians of ms per post and of the per-round ratio.

    python benchmarks/service_writers.py [--threads 8] [--posts 240] [--rounds 6]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import uuid
from pathlib import Path

from service_common import run_in_threads
from tqdm import tqdm

from app.db.migrate import upgrade
from app.db.models import Trial
from app.db.session import Database, make_sessionmaker
from app.service import experiments, lifecycle, trials
from app.service.auth import Actor
from app.service.measurements import add_measurements
from app.service.schemas import ExperimentCreate, MeasurementsIn

OPERATOR = Actor("bench", "operator")


def setup(url: str, n: int = 100) -> list[int]:
    """A tip_speed experiment with ``n`` queued trials; returns their ids."""
    db = Database(url)
    spec = ExperimentCreate(name="writers", task="tip_speed", levels=3, method="random")
    with db.write() as s:
        exp = experiments.create_experiment(s, spec, actor=OPERATOR)
        dim = exp.horizon + int(exp.with_release)
        ids = [trials.attach(s, exp.id, [0.5] * dim, note="", actor=OPERATOR).id for _ in range(n)]
    with db.write() as s:
        for tid in ids:
            s.get(Trial, tid).status = lifecycle.QUEUED
    db.dispose()
    return ids


def shared_pool(db: Database) -> Database:
    """``db`` with its write sessions on the shared pool (no writer queue)."""
    db.write_engine = db.engine
    db._write = make_sessionmaker(db.engine, write=True)
    return db


def run(db: Database, trial_ids: list[int], threads: int, posts: int) -> float:
    """ms per post of ``posts`` posts split over ``threads`` threads."""
    per = posts // threads

    def work(k: int) -> None:
        for i in range(per):
            trial_id = trial_ids[(k * per + i) % len(trial_ids)]
            body = MeasurementsIn(repeats=[{"value": 1.0, "unit": "m/s"}])
            with db.write() as s:
                add_measurements(
                    s, trial_id, body, idempotency_key=uuid.uuid4().hex, actor=OPERATOR
                )

    return run_in_threads(threads, work) / (per * threads) * 1e3


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--threads", type=int, default=8)
    ap.add_argument("--posts", type=int, default=240)
    ap.add_argument("--rounds", type=int, default=6)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        url = f"sqlite:///{Path(tmp) / 'handful.db'}"
        upgrade(url)
        trial_ids = setup(url)
        queued, shared = Database(url), shared_pool(Database(url))
        run(queued, trial_ids, args.threads, 40)  # warm-up
        run(shared, trial_ids, args.threads, 40)
        ms: dict[str, list[float]] = {"queue": [], "busy handler": []}
        for r in tqdm(range(args.rounds), desc="rounds", unit="round"):
            order = [("queue", queued), ("busy handler", shared)]
            for name, db in order if r % 2 == 0 else order[::-1]:
                ms[name].append(run(db, trial_ids, args.threads, args.posts))
        queued.dispose()
        shared.dispose()
    ratio = [q / b for q, b in zip(ms["queue"], ms["busy handler"], strict=True)]
    print(f"{args.threads} threads, {args.posts} posts x {args.rounds} rounds, 100 trials")
    for name, values in ms.items():
        print(f"  {name:13s} {statistics.median(values):6.2f} ms a post")
    spread = f"{min(ratio):.3f}-{max(ratio):.3f}"
    print(f"  queue / busy handler: {statistics.median(ratio):.3f} ({spread})")


if __name__ == "__main__":
    main()
