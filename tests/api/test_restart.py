"""kill -9 of the server mid-run: nothing committed is lost, and after a restart the optimiser
rebuilt from the database gives the same next suggestion."""

from __future__ import annotations

import threading
import time

import httpx
import numpy as np
import pytest

from app.client import HandfulAPIError
from app.db.models import IdempotencyKey, Measurement
from app.db.session import Database
from app.service.experiments import get_experiment
from app.service.trials import ask, optimizer_inputs


@pytest.mark.slow
def test_kill9_mid_run_then_restart(server_factory):
    srv = server_factory(use_cli=True)  # `handful serve`: migrations, then uvicorn
    op = srv.client("operator")
    exp = op.create_experiment(
        name="restart",
        task="tip_speed",
        levels=3,
        method="bo-lei",
        n_initial=3,
        seed=7,
        optimizer_settings={"num_restarts": 2, "raw_samples": 64},
    )
    rng = np.random.default_rng(0)
    op.import_observations(
        exp["id"],
        [
            {"theta": rng.uniform(size=10).tolist(), "objective": float(v)}
            for v in (1.0, 2.5, 1.7, 0.4)
        ],
    )
    pending = op.suggest(exp["id"], n=3)
    target = pending[0]["id"]

    acknowledged: list[tuple[str, float]] = []
    stop = threading.Event()

    def post_forever() -> None:
        c = srv.client("operator", timeout=5.0)
        i = 0
        while not stop.is_set():
            key, value = f"restart-{i}", 1.0 + (i % 7) * 0.1
            try:
                c.add_measurements(target, [{"value": value, "unit": "m/s"}], idempotency_key=key)
            except (httpx.HTTPError, HandfulAPIError):
                return
            acknowledged.append((key, value))
            i += 1

    writer = threading.Thread(target=post_forever)
    writer.start()
    deadline = time.monotonic() + 30
    while len(acknowledged) < 20 and time.monotonic() < deadline:
        time.sleep(0.05)
    srv.kill9()  # mid-run: the writer has a post in flight
    stop.set()
    writer.join(timeout=30)
    assert len(acknowledged) >= 20

    # offline, from the database file as the crash left it
    db = Database(srv.db_url)
    try:
        with db.read() as s:
            keys = {k.key for k in s.query(IdempotencyKey)}
            values = [m.value for m in s.query(Measurement).filter_by(trial_id=target)]
            inputs = optimizer_inputs(s, get_experiment(s, exp["id"]))
    finally:
        db.dispose()
    assert {k for k, _ in acknowledged} <= keys  # every acknowledged post survived
    assert len(values) in (len(acknowledged), len(acknowledged) + 1)  # + one in flight
    assert values[: len(acknowledged)] == [v for _, v in acknowledged]
    expected, _, _ = ask(inputs, 1)

    srv.start()
    op = srv.client("operator")
    t = op.get_trial(target)
    assert t["status"] == "completed" and t["n_measurements"] == len(values)
    assert t["objective"] == pytest.approx(np.mean(values), rel=1e-12)
    assert [p["id"] for p in op.list_trials(exp["id"], status="queued")] == [
        p["id"] for p in pending[1:]
    ]
    [nxt] = op.suggest(exp["id"], n=1)
    assert nxt["theta"] == expected[0].tolist()
