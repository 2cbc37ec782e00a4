"""Workers end to end: a real server (uvicorn subprocess) and real worker processes on loopback.

Covers: 2 sim workers completing a 15-trial experiment; a kill -9 of the server mid-run; a
kill -9 of a worker mid-trial (sim → requeued, hardware → needs_review); the hardware path with
confirmation (nothing unconfirmed reaches the driver); worker-token scopes; SIGTERM.
"""

from __future__ import annotations

import io
import time
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from app.client import HandfulAPIError
from app.policy import schedule_hash
from app.workers.drivers.recording import read_log

HW_LIMITS = {"nominal_pa": 100_000.0, "max_step_pa": 30_000.0, "source_pa": 205_000.0}


def sim_experiment(api, *, budget: int, preset: str = "fast", task: str = "tip_speed") -> dict:
    return api.create_experiment(
        name=f"workers e2e {task}",
        task=task,
        target="sim",
        levels=3,
        method="random",
        budget=budget,
        sim_preset=preset,
        seed=5,
    )


def hardware_experiment(api) -> dict:
    return api.create_experiment(
        name="tip speed on the stand-in",
        task="tip_speed",
        target="hardware",
        levels=5,
        method="random",
        limits=HW_LIMITS,
        seed=11,
    )


def recorded_robot(worker_factory, server, tmp_path: Path, *args: str) -> tuple[Any, Path]:
    """A hardware worker whose stand-in robot (fast preset, real time, its drift state in
    ``tmp_path``) sits behind the recording driver; ``args`` go to the worker. Returns the
    worker and the recording's log."""
    log = tmp_path / "hw.jsonl"
    robot = worker_factory(
        server,
        "hardware",
        "--driver",
        "recording",
        *("-o", "inner=standin", "-o", f"log={log}"),
        *("-o", "inner.preset=fast", "-o", "inner.realtime=true"),
        *("-o", f"inner.state_file={tmp_path / 'standin.json'}"),
        *args,
    )
    return robot, log


def statuses(api, exp_id: int) -> Counter:
    return Counter(t["status"] for t in api.list_trials(exp_id))


@pytest.mark.slow
def test_two_sim_workers_complete_a_15_trial_experiment(server_factory, worker_factory, wait_until):
    server = server_factory()
    api = server.client("operator")
    exp = sim_experiment(api, budget=15)
    trials = api.suggest(exp["id"], n=15)
    assert {t["status"] for t in trials} == {"queued"}
    workers = [
        worker_factory(server, "sim", "--max-parallel", "1", "--worker-id", f"w{i}")
        for i in range(2)
    ]
    wait_until(
        "15 completed trials",
        lambda: statuses(api, exp["id"])["completed"] == 15,
        timeout_s=180,
    )
    ran = [w.ran() for w in workers]
    assert all(ran), "both workers took a share"
    assert sorted(ran[0] + ran[1]) == sorted(t["id"] for t in trials)  # each ran exactly once
    for t in api.list_trials(exp["id"]):
        assert t["n_measurements"] == 1 and t["attempts"] == 1 and t["has_trajectory"]
        assert t["executed_pressure_schedule_pa"] == t["pressure_schedule_pa"]
        npz = np.load(io.BytesIO(api.trajectory_npz(t["id"])))
        # The uploaded trajectory is the rollout that produced the objective.
        assert t["objective"] == pytest.approx(npz["tip_speed_m_s"].max(), rel=1e-9)
        assert "qpos" in npz.files
    for w in workers:
        assert w.terminate() == 0
        assert "trial(s) run, exiting" in w.log()


@pytest.mark.slow
def test_server_kill9_mid_run_loses_nothing_and_runs_nothing_twice(
    server_factory, worker_factory, wait_until
):
    # Leases run on the wall clock while the server is down (no grace after a restart), and a
    # restart on a loaded 2-core machine can take ~50 s: leases must outlast it, or a lease
    # expires during the outage and its trial is (correctly) requeued and run again.
    server = server_factory(env={"HANDFUL_LEASE_SECONDS": "180"})
    api = server.client("operator", retries=20)
    exp = sim_experiment(api, budget=15, task="throw")
    trials = api.suggest(exp["id"], n=15)
    workers = [worker_factory(server, "sim", "--max-parallel", "1") for _ in range(2)]
    wait_until("2 completed trials", lambda: statuses(api, exp["id"])["completed"] >= 2)
    server.kill9()
    mid_run = len(Counter(tid for w in workers for tid in w.ran()))
    assert mid_run < 15, "the kill came after the run: nothing was tested"
    time.sleep(1.5)  # workers keep simulating and retrying their posts meanwhile
    server.start()
    wait_until(
        "all 15 completed after the restart",
        lambda: statuses(api, exp["id"])["completed"] == 15,
        timeout_s=240,
    )
    runs = Counter(tid for w in workers for tid in w.ran())
    assert set(runs) == {t["id"] for t in trials}
    assert max(runs.values()) == 1, f"trials run twice: {runs}"
    for t in api.list_trials(exp["id"]):
        assert t["n_measurements"] == 1, t
        assert t["objective"] is not None and t["has_trajectory"]
    for w in workers:
        assert w.terminate() == 0


@pytest.mark.slow
def test_worker_kill9_mid_trial_requeues_sim_and_holds_hardware_for_review(
    server_factory, worker_factory, wait_until, tmp_path
):
    server = server_factory(env={"HANDFUL_LEASE_SECONDS": "2"})
    api = server.client("operator")

    # --- sim: the lost trial is requeued and later completed by another worker
    exp = sim_experiment(api, budget=1, preset="reference", task="throw")
    [trial] = api.suggest(exp["id"], n=1)
    doomed = worker_factory(server, "sim", "--max-parallel", "1")
    wait_until("the sim trial to run", lambda: api.get_trial(trial["id"])["status"] == "running")
    doomed.kill9()
    assert doomed.ran() == []
    requeued = wait_until(
        "requeue after the lease expires",
        lambda: (t := api.get_trial(trial["id"]))["status"] == "queued" and t,
        timeout_s=30,
    )
    assert "requeued" in requeued["status_reason"] and requeued["attempts"] == 1
    rescuer = worker_factory(server, "sim", "--max-parallel", "1", "--max-trials", "1")
    assert rescuer.wait() == 0
    done = api.get_trial(trial["id"])
    assert done["status"] == "completed" and done["attempts"] == 2 and done["n_measurements"] == 1

    # --- hardware: the lost trial goes to needs_review and is never rerun on its own
    hw = hardware_experiment(api)
    [hw_trial] = api.suggest(hw["id"], n=1)
    assert hw_trial["status"] == "awaiting_confirmation"
    api.preview_and_confirm(hw_trial)
    robot, log = recorded_robot(worker_factory, server, tmp_path)
    wait_until("the robot to start the trial", lambda: len(read_log(log)) == 1)
    robot.kill9()
    review = wait_until(
        "needs_review after the lease expires",
        lambda: (t := api.get_trial(hw_trial["id"]))["status"] == "needs_review" and t,
        timeout_s=30,
    )
    assert "never rerun on its own" in review["status_reason"]
    second = worker_factory(server, "hardware", "--driver", "standin", "--idle-exit", "2")
    assert second.wait() == 0 and second.ran() == []
    assert api.get_trial(hw_trial["id"])["status"] == "needs_review"


@pytest.mark.slow
def test_hardware_worker_runs_only_confirmed_trials_and_reports_tracking(
    server_factory, worker_factory, tmp_path
):
    # 1 s leases against a 5 s real-time trial: only heartbeats keep the lease alive.
    server = server_factory(env={"HANDFUL_LEASE_SECONDS": "1"})
    api = server.client("operator")
    exp = hardware_experiment(api)
    confirmed, unconfirmed = api.suggest(exp["id"], n=2)
    # A confirmation binds the exact schedule: a wrong hash is refused.
    wrong = schedule_hash(np.asarray(confirmed["pressure_schedule_pa"]) + 1.0, None)
    with pytest.raises(HandfulAPIError) as err:
        api.confirm_trial(confirmed["id"], wrong)
    assert err.value.status in (409, 422)
    api.preview_and_confirm(confirmed)
    robot, log = recorded_robot(
        worker_factory,
        server,
        tmp_path,
        *("-o", "inner.fault_probability=0", "-o", "inner.tracker_loss_probability=0"),
        *("--idle-exit", "3"),
    )
    assert robot.wait() == 0, robot.log()
    reached = read_log(log)
    assert [e["trial_id"] for e in reached] == [confirmed["id"]]
    assert schedule_hash(reached[0]["pressure_schedule_pa"], None) == confirmed["schedule_hash"]
    done = api.get_trial(confirmed["id"])
    assert done["status"] == "completed", done["status_reason"]
    assert done["attempts"] == 1 and done["duration_s"] >= 4.9  # real time, never lost
    assert done["executed_pressure_schedule_pa"] == confirmed["pressure_schedule_pa"]
    track = np.load(io.BytesIO(api.trajectory_npz(confirmed["id"])))
    assert set(track.files) >= {"time_s", "tip_pos_m", "tip_vel_m_s"}
    assert 400 < len(track["time_s"]) <= 451  # ~90 Hz over 5 s
    assert 0.5 < done["objective"] < 5.0  # m/s, from the noisy tracking stream
    assert api.get_trial(unconfirmed["id"])["status"] == "awaiting_confirmation"


def test_worker_token_cannot_create_suggest_measure_confirm_or_fail(api, worker_api):
    exp = sim_experiment(api, budget=2)
    [trial] = api.suggest(exp["id"], n=1)
    hw = hardware_experiment(api)
    [hw_trial] = api.suggest(hw["id"], n=1)
    forbidden = [
        lambda: worker_api.create_experiment(name="x", task="throw", levels=2),
        lambda: worker_api.suggest(exp["id"], n=1),
        lambda: worker_api.add_measurements(trial["id"], [{"value": 1.0, "unit": "m/s"}]),
        lambda: worker_api.confirm_trial(hw_trial["id"], hw_trial["schedule_hash"]),
        lambda: worker_api.fail_trial(trial["id"], "no"),
        lambda: worker_api.attach_trial(exp["id"], [0.5] * 10),
    ]
    for call in forbidden:
        with pytest.raises(HandfulAPIError) as err:
            call()
        assert err.value.status == 403
    # What a worker token may do (claim, heartbeat, report) the tests above do through workers.
    assert api.get_trial(hw_trial["id"])["confirmed_hash"] is None
    assert api.get_trial(trial["id"])["n_measurements"] == 0


def test_worker_with_a_viewer_token_exits_with_one_line(live_server, worker_factory):
    proc = worker_factory(live_server, "sim", "--max-parallel", "1", role="viewer")
    assert proc.wait(timeout_s=60) == 1
    last = proc.log().strip().splitlines()[-1]
    assert last.startswith("error: the server refused the worker: claim: HTTP 403")
