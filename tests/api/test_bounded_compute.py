"""Suggestions run within a time budget and ``/model`` reuses their fit (issue 16, finding 4),
over HTTP: one server with a 30 s budget (a small BO suggestion must fit in it on a loaded
2-core machine; the big one below must not)."""

from __future__ import annotations

import time

import httpx
import numpy as np
import pytest

SERVER_ENV = {"HANDFUL_SUGGEST_TIMEOUT_S": "15", "HANDFUL_COMPUTE_WORKERS": "1"}


def _observations(n: int, dim: int = 10, seed: int = 0) -> list[dict]:
    rng = np.random.default_rng(seed)
    return [
        {"theta": rng.random(dim).tolist(), "objective": float(rng.random()), "unit": "m/s"}
        for _ in range(n)
    ]


def test_model_reuses_the_suggestions_fit(module_server):
    op = module_server.client("operator")
    exp = op.create_experiment(name="m", task="tip_speed", levels=3, n_initial=2)
    op.import_observations(exp["id"], _observations(5))
    headers = {"Authorization": f"Bearer {module_server.tokens['viewer']}"}
    url = f"{module_server.url}/api/experiments/{exp['id']}/model"
    op.suggest(exp["id"])
    r = httpx.get(url, headers=headers, timeout=60)
    assert r.status_code == 200 and r.headers["X-Model-Cache"] == "hit"
    assert len(r.json()["slices"]) == 10
    assert httpx.get(url, headers=headers, timeout=60).headers["X-Model-Cache"] == "hit"


@pytest.mark.slow
def test_a_suggestion_past_its_budget_is_a_quick_503_and_stops(module_server):
    op = module_server.client("operator")
    exp = op.create_experiment(
        name="slow",
        task="tip_speed",
        levels=3,
        n_initial=2,
        optimizer_settings={"num_restarts": 64, "raw_samples": 8192},
    )
    op.import_observations(exp["id"], _observations(3000))
    headers = {"Authorization": f"Bearer {module_server.tokens['operator']}"}
    t0 = time.monotonic()
    r = httpx.post(
        f"{module_server.url}/api/experiments/{exp['id']}/suggest",
        json={"n": 1},
        headers=headers,
        timeout=120,
    )
    elapsed = time.monotonic() - t0
    assert r.status_code == 503, r.text
    assert r.json()["code"] == "compute_timeout" and "15 s budget" in r.json()["detail"]
    assert int(r.headers["Retry-After"]) >= 1
    assert elapsed < 35
    assert op.get_experiment(exp["id"])["n_trials"] == 3000  # nothing stored
    # the stopped process is replaced: a small suggestion works again
    small = op.create_experiment(name="small", task="tip_speed", levels=3, method="random")
    deadline = time.monotonic() + 60
    while True:
        r = httpx.post(
            f"{module_server.url}/api/experiments/{small['id']}/suggest",
            json={"n": 1},
            headers=headers,
            timeout=60,
        )
        if r.status_code != 503 or time.monotonic() > deadline:
            break
        time.sleep(1)
    assert r.status_code == 201
