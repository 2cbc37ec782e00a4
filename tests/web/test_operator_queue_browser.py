"""The operator's queue and forms in Chromium: what needs me on the experiments list (live),
every trial awaiting a measurement within reach, Stop on a running hardware trial, the
forms' rules in their own units and words, trial numbers, sim/throw pages, offline docs."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from tests.web.test_dashboard_browser import login


def test_the_queue_an_operator_lives_in(
    dashboard_server: Any, hw_exp: Any, page: Any, screenshots: Path
):
    server = dashboard_server
    api, worker = server.client("operator"), server.client("worker")
    exp = hw_exp(api, name="queue", budget=6, n_initial=3)
    a, b = api.suggest(exp["id"], n=2)
    login(page, server, "operator")
    # the list: what awaits confirmation / measurement, live (no reload)
    row = page.locator(f"tr[data-id='{exp['id']}']")
    row.locator("td[data-what='awaiting_confirmation']").filter(has_text="2").wait_for()
    api.preview_and_confirm(a)
    [claim] = worker.claim("hw", "hardware")
    worker.report_result(a["id"], claim["lease_id"])  # ran; the tape has not spoken yet
    row.locator("td[data-what='awaiting_measurement']").filter(has_text="1").wait_for()
    row.locator("td[data-what='awaiting_confirmation']").filter(has_text="1").wait_for()
    page.screenshot(path=str(screenshots / "experiments_queue.png"))

    # the experiment page: the trial that ran stays within reach when others come
    page.goto(f"{server.url}/experiments/{exp['id']}")
    api.suggest(exp["id"])
    page.locator("#awaiting-list button").filter(has_text=f"Measure trial {a['index']}").click()
    page.locator("#next-title").filter(has_text=f"trial {a['index']}").wait_for()
    page.fill("input[aria-label='repeat 1 value']", "1,29")
    page.click("#measure-save")
    page.locator("#measure-error").filter(
        has_text="“1,29” has a comma: type the decimals after a point (1.29)"
    ).wait_for()
    assert api.get_trial(a["id"])["n_measurements"] == 0
    page.fill("input[aria-label='repeat 1 value']", "1.29")
    page.click("#measure-save")
    page.wait_for_selector("#exp-ok:has-text('Saved 1 repeat for trial 1')")
    assert api.get_trial(a["id"])["objective"] == 1.29
    page.locator("#awaiting-card").wait_for(state="hidden")

    # a running hardware trial: elapsed time and a Stop that fails it with the reason
    api.preview_and_confirm(b)
    [claim] = worker.claim("hw", "hardware")
    page.locator("#awaiting-list")  # (nothing awaits a measurement now)
    page.locator("#next-title").filter(has_text=f"trial {b['index']}").wait_for()
    page.locator("#elapsed").filter(has_text=re.compile(r"\d+\.\d s")).wait_for()
    page.screenshot(path=str(screenshots / "experiment_running.png"))
    page.fill("#stop-reason", "the gripper opened early")
    page.click("#stop-button")
    page.wait_for_selector("#exp-ok:has-text('stopped')")
    stopped = api.get_trial(b["id"])
    assert (stopped["status"], stopped["status_reason"]) == ("failed", "the gripper opened early")

    # one numbering: the audit log names trials by their number, never a database id
    page.click("#audit-box summary")
    page.locator("#exp-audit-table td a").filter(has_text=f"trial {b['index']}").first.wait_for()
    cells = page.locator("#exp-audit-table td:nth-child(4)").all_inner_texts()
    assert all(c == "—" or re.fullmatch(r"trial \d+", c) for c in cells), cells

    # the budget field: "1e" and a budget below the trials run are refused in words
    page.fill("#exp-budget-input", "1e")
    page.click("#exp-save")
    page.locator("#exp-error").filter(has_text="“1e” is not a whole number").wait_for()
    page.fill("#exp-budget-input", "2")
    page.click("#exp-save")
    page.locator("#exp-error").filter(has_text="below the 3 trials").wait_for()
    assert api.get_experiment(exp["id"])["budget"] == 6
    page.screenshot(path=str(screenshots / "experiment_queue.png"), full_page=True)

    # a throw's trial page: no flat plate-force plot
    page.goto(f"{server.url}/trials/{a['id']}")
    page.wait_for_selector("#measurements-table td.m-value")
    assert page.locator("#force-plot .main-svg").count() == 0


def test_forms_say_what_is_wrong_in_their_units(
    dashboard_server: Any, page: Any, screenshots: Path
):
    server = dashboard_server
    api = server.client("operator")
    login(page, server, "operator")
    page.goto(f"{server.url}/experiments/new")
    page.fill("#f-name", "too wide")
    page.select_option("#f-task", "throw")
    page.select_option("#f-target", "hardware")
    page.fill("#f-budget", "5")  # below the 12 initial trials of the default
    page.click("#create-button")
    page.locator("[data-field='n_initial'] .field-error").filter(
        has_text="12 initial random trials do not fit in a budget of 5 trials"
    ).wait_for()
    page.fill("#f-budget", "40")
    page.fill("#f-source", "1000000000")  # a kPa/Pa slip: 1e9 kPa
    page.click("#create-button")
    note = page.locator("[data-field='source_pa'] .field-error")
    note.filter(has_text="1e+09 kPa is above this robot's ceiling of 205 kPa").wait_for()
    assert "source_pa" not in note.inner_text() and "[0]" not in note.inner_text()
    page.screenshot(path=str(screenshots / "new_experiment_errors.png"), full_page=True)
    assert [e["name"] for e in api.list_experiments()] == []
    # within the ceilings it is created; the operator picks what the objective is made of
    page.fill("#f-source", "205")
    page.select_option("#f-objective_sources", "tracker")
    page.click("#create-button")
    page.wait_for_url(re.compile(r"/experiments/\d+$"))
    [made] = api.list_experiments()
    assert made["objective_sources"] == ["tracker", "imported"]
    page.locator("#exp-summary").filter(has_text="from tracker + imported").wait_for()

    # a sim trial is scored by the simulator: no operator measurement form
    sim = api.create_experiment(name="sim", task="tip_speed", levels=3, sim_preset="fast")
    [t] = api.suggest(sim["id"])
    api.run_trial(t["id"])
    page.goto(f"{server.url}/trials/{t['id']}")
    page.wait_for_selector("#measurements-table td.m-value")
    assert page.locator("#measure-form").count() == 0

    # the API docs render from the server alone (this browser reaches nothing else)
    page.goto(f"{server.url}/docs")
    page.locator(".swagger-ui .info .title").filter(has_text="handful").wait_for()
    page.screenshot(path=str(screenshots / "api_docs.png"))
