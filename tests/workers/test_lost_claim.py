"""A claim whose answer is lost (the server committed it, then the connection died): the
worker's retry names the same claim and gets the same lease back, so the trial runs now, once,
instead of waiting out its lease (tests/workers/test_workers_e2e.py kills a real server in that
window only by chance)."""

from __future__ import annotations

from typing import Any

import httpx

from app.workers.drivers import load_driver
from app.workers.hardware import HardwareWorker
from app.workers.sim import SimWorker


class LosesFirstAnswer:
    """The worker's real client, except that the first claim's answer never arrives: the
    server stores it, the worker sees the connection drop."""

    def __init__(self, client: Any) -> None:
        self.client = client
        self.claim_ids: list[str | None] = []

    def claim(self, *args: Any, **kwargs: Any) -> Any:
        self.claim_ids.append(kwargs.get("claim_id"))
        answer = self.client.claim(*args, **kwargs)
        if len(self.claim_ids) == 1:
            raise httpx.RemoteProtocolError("Server disconnected without sending a response.")
        return answer

    def __getattr__(self, name: str) -> Any:
        return getattr(self.client, name)


def test_the_sim_workers_retry_gets_the_lost_claims_lease(op, worker, new_exp):
    exp = new_exp(op, name="lost claim")
    [trial] = op.suggest(exp["id"])
    client = LosesFirstAnswer(worker)
    [claim] = SimWorker(client, worker_id="sim-lost", max_parallel=1)._claim(1)
    assert claim["trial"]["id"] == trial["id"] and claim["trial"]["attempts"] == 1
    assert len(client.claim_ids) == 2 and client.claim_ids[0] == client.claim_ids[1] is not None
    assert op.get_trial(trial["id"])["status"] == "running"
    assert worker.heartbeat(claim["lease_id"])["status"] == "active"  # the worker holds it


def test_the_hardware_workers_retry_runs_the_lost_claims_trial_once(op, worker, new_exp):
    exp = new_exp(op, name="lost hardware claim", target="hardware", sim_preset="fast")
    [trial] = op.suggest(exp["id"])
    op.preview_and_confirm(trial)
    client = LosesFirstAnswer(worker)
    driver = load_driver(
        "standin", preset="fast", state_file="", fault_probability="0",
        tracker_loss_probability="0",
    )  # fmt: skip
    assert HardwareWorker(client, driver, worker_id="hw-lost").run(max_trials=1) == 1
    assert len(client.claim_ids) == 2 and client.claim_ids[0] == client.claim_ids[1] is not None
    after = op.get_trial(trial["id"])
    assert after["attempts"] == 1 and after["status"] not in ("queued", "running"), after
