"""Stop: an operator fails a running hardware trial with a reason; the worker notices its
revoked lease within a second and aborts the driver, which vents to nominal."""

from __future__ import annotations

import threading
import time

import numpy as np

from app.workers.drivers import load_driver
from app.workers.hardware import HardwareWorker


def test_stopping_a_running_hardware_trial_aborts_the_driver(op, worker, new_exp):
    # its own server: a claim on the shared one could take another test's queued trial
    api, worker_api = op, worker
    exp = new_exp(api, name="stop", target="hardware", sim_preset="fast")
    [trial] = api.suggest(exp["id"])
    api.preview_and_confirm(trial)
    driver = load_driver(
        "standin",
        preset="fast",
        realtime="1",  # a 5 s schedule takes 5 s, like the robot
        state_file="",
        fault_probability="0",
        tracker_loss_probability="0",
    )
    hw = HardwareWorker(worker_api, driver, worker_id="hw-stop")
    [claim] = worker_api.claim("hw-stop", "hardware")
    outcome: list = []
    runner = threading.Thread(target=lambda: outcome.append(hw.run_one(claim)))
    t0 = time.monotonic()
    runner.start()
    time.sleep(1.0)
    assert api.get_trial(trial["id"])["status"] == "running"
    stopped = api.fail_trial(trial["id"], "stopped: the arm swung towards the table")
    assert stopped["status"] == "failed"
    runner.join(timeout=20)
    assert not runner.is_alive()
    assert time.monotonic() - t0 < 4.5  # aborted, not run to the end of its 5 s
    [out] = outcome
    assert out.execution.fault == "aborted by the worker; vented to nominal"
    executed = np.asarray(out.execution.executed_pressure_schedule_pa)
    assert np.allclose(executed[-1], 100_000.0)  # vented to nominal
    final = api.get_trial(trial["id"])
    assert final["status"] == "failed"
    assert final["status_reason"] == "stopped: the arm swung towards the table"
    assert "trial.abort" in [a["action"] for a in final["audit"]]
