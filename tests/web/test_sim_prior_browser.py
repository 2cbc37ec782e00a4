"""From simulation to the robot in Chromium (issue 18): a hardware experiment on the stand-in
starts its sim prior, its sim trials run, the next suggestion leans on it, the safety gate
shows the sim twin's prediction beside the GP's, the experiment page plots hardware vs
twin, and a reference trial runs on schedule and the drift chart gains it. A link whose
task, policy or hold differs is refused on the new-experiment form."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest

from app.workers.drivers.standin import StandinDriver
from app.workers.hardware import HardwareWorker
from tests.web.test_dashboard_browser import login
from tests.web.test_drift_browser import run_until_reference_scored, standin_worker

LIMITS = {"nominal_pa": 100_000.0, "max_step_pa": 30_000.0, "source_pa": 205_000.0}
QUICK = {"num_restarts": 2, "raw_samples": 64, "fit_maxiter": 20}
#: the stand-in worker process: no faults (a faulted trial waits for a person's review)
STEADY = {"state_file": "", "preset": "fast", "fault_probability": "0"}
STEADY["tracker_loss_probability"] = "0"


@pytest.mark.slow
def test_a_linked_sim_and_hardware_pair_on_the_standin(
    dashboard_server_factory: Any, page: Any, screenshots: Path, tmp_path: Path
):
    # one compute process (one torch import) for both experiments' suggestions
    server = dashboard_server_factory(HANDFUL_TWIN_INTERVAL_S="0.3", HANDFUL_COMPUTE_WORKERS="1")
    api, worker = server.client("operator"), server.client("worker")
    other = api.create_experiment(name="sim P=5", task="tip_speed", levels=5, sim_preset="fast")
    hw = api.create_experiment(
        name="arm",
        task="tip_speed",
        target="hardware",
        levels=3,
        limits=LIMITS,
        optimizer_settings=QUICK,
    )
    login(page, server, "operator")

    # the form refuses a sim prior of another policy, saying what differs
    page.goto(f"{server.url}/experiments/new")
    page.fill("#f-name", "mismatched")
    page.select_option("#f-target", "hardware")
    page.fill("#f-levels", "3")
    page.locator(f"#f-sim_prior option[value='{other['id']}']").wait_for(state="attached")
    page.select_option("#f-sim_prior", str(other["id"]))
    page.click("#create-button")
    page.locator("[data-field='sim_prior_experiment_id'] .field-error").filter(
        has_text="the pressure levels P differ (3 here, 5 there)"
    ).wait_for()
    assert [e["name"] for e in api.list_experiments()] == ["arm", "sim P=5"]

    # the experiment page starts a sim prior; its trials run in the simulator (the service's
    # run, what a sim worker does, without starting one: tests/api covers the workers' path)
    page.goto(f"{server.url}/experiments/{hw['id']}")
    page.fill("#sim-prior-n", "4")
    page.click("#sim-prior-start")
    page.wait_for_selector("#exp-ok:has-text('Sim prior started')")
    sim_id = api.get_experiment(hw["id"])["sim_prior_experiment_id"]
    assert sim_id is not None and len(api.list_trials(sim_id, status="queued")) == 4
    for queued in api.list_trials(sim_id, status="queued"):
        assert api.run_trial(queued["id"])["status"] == "completed"
    assert api.sim_prior(hw["id"])["n_scored"] == 4

    # the next suggestion leans on it; the gate shows the twin beside the GP
    page.click("#suggest-button")
    page.locator("#sim-prior-state").filter(has_text="4 scored sim trials").wait_for()
    gate = page.locator("#gate-predictions")
    gate.locator("#gate-basis").filter(has_text="one of the sim prior's best θ").wait_for()
    gate.locator("#gate-twin").filter(has_text=re.compile(r"tip speed \d")).wait_for()
    assert (
        "no bend limit hit" in gate.inner_text() or "bend limit hit at joint" in gate.inner_text()
    )
    [t] = api.list_trials(hw["id"])
    assert t["suggestion_basis"]["mode"] == "multitask" and t["suggestion_basis"]["n_prior"] == 4
    page.screenshot(path=str(screenshots / "sim_prior_gate.png"))

    # the stand-in runs it; the page plots hardware vs twin with the discrepancy
    api.preview_and_confirm(t)
    robot = StandinDriver(state_file="", preset="fast")
    assert HardwareWorker(worker, robot, poll_s=0.2).run(max_trials=1) == 1
    done = api.get_trial(t["id"])
    assert done["status"] == "completed" and done["objective"] is not None
    api.wait_twin(t["id"], "executed")
    [row] = api.experiment_twins(hw["id"])
    page.locator("#twin-empty").wait_for(state="hidden", timeout=30_000)
    page.locator("#twin-plot .main-svg").first.wait_for()
    assert row["twin"]["kind"] == "executed" and row["discrepancy"] is not None
    page.screenshot(path=str(screenshots / "sim_prior_experiment.png"), full_page=True)

    # a reference trial runs on schedule (every 2nd hardware trial: the incumbent, trial 1)
    # on the real stand-in worker, and the page's drift chart gains it
    api.set_reference(hw["id"], every=2)
    with standin_worker(server, tmp_path, options=STEADY):
        ref = run_until_reference_scored(page, api, hw["id"])
    assert ref["source"] == "reference" and ref["index"] == 2 and ref["theta"] == t["theta"]
    assert [p["index"] for p in api.drift(hw["id"])["points"]] == [2]

    page.goto(f"{server.url}/trials/{t['id']}")
    page.locator("#trial-facts").filter(has_text="Sim twin of what ran").wait_for()
    assert "hardware − twin" in page.locator("#trial-facts").inner_text()
