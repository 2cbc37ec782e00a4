"""No request waits for the database on the event loop (issue 16, finding 2): while another
program holds SQLite's write lock, /health stays fast, a write is a quick 503 with
Retry-After, and HandfulClient retries it within its deadline."""

from __future__ import annotations

import subprocess
import sys
import threading
import time

import httpx

SERVER_ENV = {"HANDFUL_DB_BUSY_TIMEOUT_S": "2"}

HOLD = """
import sqlite3, sys, time
c = sqlite3.connect(sys.argv[1], isolation_level=None)
c.execute("BEGIN IMMEDIATE")
print("locked", flush=True)
time.sleep(float(sys.argv[2]))
c.rollback()
"""


def _hold_write_lock(server, seconds: float) -> subprocess.Popen:
    proc = subprocess.Popen(
        [sys.executable, "-c", HOLD, str(server.data_dir / "handful.db"), str(seconds)],
        stdout=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout.readline().strip() == "locked"
    return proc


def _queued_trial(server) -> int:
    op = server.client("operator")
    exp = op.create_experiment(name="loop", task="tip_speed", levels=3, method="random")
    return op.suggest(exp["id"])[0]["id"]


def test_health_stays_fast_while_another_program_holds_the_write_lock(module_server):
    trial_id = _queued_trial(module_server)
    headers = {
        "Authorization": f"Bearer {module_server.tokens['operator']}",
        "Idempotency-Key": "loop-1",
    }
    replies: list[tuple[httpx.Response, float]] = []

    def post() -> None:
        t0 = time.perf_counter()
        r = httpx.post(
            f"{module_server.url}/api/trials/{trial_id}/measurements",
            json={"repeats": [{"value": 1.0, "unit": "m/s"}]},
            headers=headers,
            timeout=60,
        )
        replies.append((r, time.perf_counter() - t0))

    holder = _hold_write_lock(module_server, 6)
    try:
        posts = [threading.Thread(target=post) for _ in range(4)]
        for t in posts:
            t.start()
        latencies = []
        with httpx.Client(base_url=module_server.url, timeout=60) as client:
            while any(t.is_alive() for t in posts):
                t0 = time.perf_counter()
                assert client.get("/health").status_code == 200
                latencies.append(time.perf_counter() - t0)
                time.sleep(0.02)
        for t in posts:
            t.join()
    finally:
        holder.wait(timeout=30)
    assert len(latencies) > 20
    assert max(latencies) < 0.5, sorted(latencies)[-5:]
    for r, elapsed in replies:  # a quick, clear refusal: nothing stored
        assert r.status_code == 503 and r.json()["code"] == "database_busy"
        assert r.headers["Retry-After"] == "1"
        assert elapsed < 5
    trial = module_server.client("viewer").get_trial(trial_id)
    assert trial["n_measurements"] == 0


def test_the_client_retries_a_busy_database_within_its_deadline(module_server):
    trial_id = _queued_trial(module_server)
    holder = _hold_write_lock(module_server, 4)
    try:
        op = module_server.client("operator")
        t0 = time.perf_counter()
        receipt = op.add_measurements(trial_id, [{"value": 2.0, "unit": "m/s"}])
        elapsed = time.perf_counter() - t0
    finally:
        holder.wait(timeout=30)
    assert receipt["stored"] and receipt["status"] == "completed"
    assert 3 < elapsed < 15  # it waited for the lock to go, retrying
    # and gives up at its deadline with the server's 503
    holder = _hold_write_lock(module_server, 8)
    try:
        impatient = module_server.client("operator")
        impatient.busy_deadline_s = 1.0
        t1 = time.perf_counter()
        try:
            impatient.add_measurements(trial_id, [{"value": 2.0, "unit": "m/s"}])
        except Exception as exc:  # HandfulAPIError
            assert exc.status == 503 and exc.code == "database_busy"
        else:
            raise AssertionError("a 503 was expected")
        assert time.perf_counter() - t1 < 7
    finally:
        holder.wait(timeout=30)
