"""The dashboard in a real browser (Playwright + Debian Chromium) against a real server process.

Screenshots of every page go to ``test-output/screenshots/``.
"""

from __future__ import annotations

import io
import math
import re
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from PIL import Image

REPO = Path(__file__).resolve().parents[2]
PASSWORD = "correct horse battery"  # the shared fixtures' password for every user

pytestmark = pytest.mark.browser


def login(page: Any, server: Any, username: str, screenshot: Path | None = None) -> None:
    """Log in through the login form; lands on the experiments list."""
    page.goto(f"{server.url}/experiments")
    page.wait_for_url(re.compile(r"/login"))
    if screenshot is not None:
        page.screenshot(path=str(screenshot))
    page.fill("#username", username)
    page.fill("#password", PASSWORD)
    page.click("#login-form button[type=submit]")
    page.wait_for_url(re.compile(r"/experiments$"))


def arm_pixels(png: bytes) -> int:
    """How many pixels look like the arm's orange-red disks (R high, G and B low)."""
    rgb = np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(int)
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    return int(np.count_nonzero((r > 150) & (g < 110) & (b < 90)))


def wait_for_drawn_arm(page: Any, timeout_s: float = 150.0) -> bytes:
    """The viser canvas inside the 3D iframe, once it shows the arm; its screenshot (PNG)."""
    frame = page.frame_locator("#viz-frame")
    canvas = frame.locator("canvas").first
    canvas.wait_for(state="visible", timeout=int(timeout_s * 1000))
    page.evaluate("document.getElementById('viz-frame').scrollIntoView({block: 'center'})")
    deadline = time.monotonic() + timeout_s
    png = b""
    while time.monotonic() < deadline:
        # A clip of the page, not an element shot: viser keeps resizing its canvas (adaptive
        # pixel ratio), so it is never "stable" for Playwright.
        # Generous: the viser client's first load (shader compiles in software GL) can hold the
        # tab's main thread for tens of seconds on a loaded 2-core machine.
        box = page.locator("#viz-frame").bounding_box(timeout=timeout_s * 1000)
        png = page.screenshot(clip=box, timeout=timeout_s * 1000) if box else b""
        if png and arm_pixels(png) > 200:
            return png
        time.sleep(1.0)
    found = arm_pixels(png) if png else 0
    raise AssertionError(f"the viser canvas never drew the arm ({found} arm pixels)")


def fmt(x: float, digits: int = 3) -> str:
    """The dashboard's number format (ui.js fmt) for ordinary magnitudes."""
    return f"{x:.{digits}f}"


@pytest.mark.slow
def test_operator_loop_on_the_standin_robot(
    dashboard_server: Any, page: Any, screenshots: Path, tmp_path: Path
) -> None:
    """Log in, create a hardware experiment, suggest, preview in 3D, confirm, the stand-in
    worker runs it, enter two tape measurements; table and plot show mean ± SEM."""
    server = dashboard_server
    api = server.client("operator")
    page.goto(f"{server.url}/login")
    page.fill("#username", "operator")
    page.fill("#password", "wrong password")
    page.click("#login-form button[type=submit]")
    page.locator("#login-error").filter(has_text="wrong username or password").wait_for()
    login(page, server, "operator", screenshot=screenshots / "login.png")
    page.screenshot(path=str(screenshots / "experiments_empty.png"))

    # 2. create a hardware experiment (throw: the cube's distance is measured by tape, in m)
    page.click("#nav-new")
    page.wait_for_url(re.compile(r"/experiments/new$"))
    # the form is live once its script has checked the login and filled in its notes
    page.wait_for_function("document.querySelector('#f-dim-note').textContent !== ''")
    page.fill("#f-name", "throw on the stand-in")
    page.select_option("#f-task", "throw")
    page.select_option("#f-target", "hardware")
    page.select_option("#f-objective_unit", "m")
    page.fill("#f-budget", "20")
    # a full-page screenshot here left the next click without effect in Chromium 156: the
    # viewport's is enough
    page.screenshot(path=str(screenshots / "new_experiment.png"))
    page.click("#create-button")
    page.wait_for_url(re.compile(r"/experiments/\d+$"))
    experiment_id = int(page.url.rsplit("/", 1)[1])
    experiment = api.get_experiment(experiment_id)
    assert (experiment["task"], experiment["target"]) == ("throw", "hardware")
    assert experiment["method"] == "bo-lei-default"  # the form starts on handful's default
    assert experiment["limits"]["max_step_pa"] == pytest.approx(30_000.0)

    # 3. get a suggestion: the next-trial card shows its schedule as a 12 × H heatmap
    page.click("#suggest-button")
    page.wait_for_selector("#next-body:not([hidden])")
    [trial] = api.list_trials(experiment_id)
    assert trial["status"] == "awaiting_confirmation"
    heat = page.evaluate("document.getElementById('heatmap').data[0].z")
    assert len(heat) == 12 and len(heat[0]) == 10
    assert np.allclose(np.asarray(heat) * 1000.0, np.asarray(trial["pressure_schedule_pa"]).T)

    # 4. confirming without a preview of this schedule is refused by the server, in words
    page.check("#confirm-check")
    page.click("#confirm-button")
    page.locator("#confirm-error").filter(has_text="not previewed").wait_for()
    assert api.get_trial(trial["id"])["status"] == "awaiting_confirmation"
    page.screenshot(path=str(screenshots / "experiment_confirm_refused.png"))
    page.reload()
    page.wait_for_selector("#confirm-button")

    # 4b. preview: a sim rollout of exactly this schedule, drawn by viser, next to its gate
    page.click("#preview-button")
    page.wait_for_selector("#viz-frame", timeout=120_000)
    assert "predicted max tip speed" in page.inner_text("#viz-legend")
    canvas_png = wait_for_drawn_arm(page)
    (screenshots / "preview_canvas.png").write_bytes(canvas_png)
    page.evaluate("document.getElementById('next-card').scrollIntoView({block: 'start'})")
    page.screenshot(path=str(screenshots / "experiment_preview.png"))
    # the preview and the gate of the same trial side by side, both in the 1280×800 viewport
    assert page.inner_text("#viz-title") == f"preview of trial {trial['index']}"
    assert f"trial {trial['index']}" in page.inner_text("#trial-actions h3:has-text('Safety gate')")
    for selector in ("#confirm-button", "#viz-frame"):
        box = page.locator(selector).bounding_box()
        assert box is not None and box["y"] >= 0 and box["y"] + box["height"] <= 800, (
            selector,
            box,
        )
    gate, frame = (page.locator(s).bounding_box() for s in ("#confirm-button", "#viz-frame"))
    assert gate["x"] + gate["width"] <= frame["x"]  # side by side
    viser_src = page.get_attribute("#viz-frame", "src")
    # through the main port (proxied to viser): a lab that forwards one port keeps the 3D view
    assert viser_src.startswith(f"{server.url}/viz/client/") and "viz%2Fws%2Fview" in viser_src
    # framed by our own page only: the proxied client may be framed by its own origin, every
    # other reply keeps the security headers' "no frames at all"
    client = httpx.get(viser_src, timeout=30)
    assert "frame-ancestors 'self'" in client.headers["content-security-policy"]
    assert client.headers["x-frame-options"] == "SAMEORIGIN"
    page_reply = httpx.get(f"{server.url}/experiments/{trial['experiment_id']}", timeout=30)
    assert "frame-ancestors 'none'" in page_reply.headers["content-security-policy"]
    page.click("#viz-close")  # software WebGL is heavy on a small CI machine

    # 5. confirm: the page sends the hash of the schedule it showed
    page.uncheck("#confirm-check")
    page.click("#confirm-button")
    assert "Tick the box" in page.inner_text("#confirm-error")
    assert api.get_trial(trial["id"])["status"] == "awaiting_confirmation"
    page.check("#confirm-check")
    page.click("#confirm-button")
    page.wait_for_selector("#exp-ok:has-text('confirmed and queued')")
    confirmed = api.get_trial(trial["id"])
    assert confirmed["status"] == "queued"
    assert confirmed["confirmed_hash"] == trial["schedule_hash"]
    assert confirmed["confirmed_by"] == "operator"

    # 6. the stand-in hardware worker runs it
    worker = subprocess.run(
        [
            sys.executable,
            "-m",
            "app.cli",
            "worker",
            "hardware",
            "--server",
            server.url,
            "--token",
            server.tokens["worker"],
            "--driver",
            "standin",
            "-o",
            "fault_probability=0",
            "-o",
            "tracker_loss_probability=0",
            "-o",
            f"state_file={tmp_path / 'standin.json'}",
            "--max-trials",
            "1",
            "--poll",
            "0.2",
            "--idle-exit",
            "60",
        ],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=180,
    )
    assert worker.returncode == 0, worker.stderr[-3000:]
    ran = api.get_trial(trial["id"])
    assert ran["status"] in ("running", "completed"), ran["status"]

    # 7. the page notices by itself (polling) and offers the measurement form
    page.wait_for_selector("#measure-form", timeout=20_000)
    page.fill("input[aria-label='repeat 1 value']", "1.52")
    page.click("#measure-add")
    page.fill("input[aria-label='repeat 2 value']", "1.48")
    page.fill("input[aria-label='repeat 2 note']", "second tape")
    assert page.inner_text("#measure-summary") == "mean 1.500 ± 0.020 (SEM) m over 2 repeats"
    # a live update while the operator types (here: a colleague's measurement from a script)
    # re-renders the card but keeps the repeats being typed
    api.add_measurements(trial["id"], [{"value": 1.50, "unit": "m", "note": "from a script"}])
    page.get_by_text(f"Enter measurement for trial {trial['index']} (has 1)").wait_for(
        timeout=20_000
    )
    assert page.input_value("input[aria-label='repeat 1 value']") == "1.52"
    assert page.input_value("input[aria-label='repeat 2 note']") == "second tape"
    page.click("#measure-save")
    page.wait_for_selector("#exp-ok:has-text('Saved 2 repeats')")

    # 8. table and plot show the trial's mean ± SEM over all its measurements
    measured = api.get_trial(trial["id"])
    values = [m["value"] for m in measured["measurements"]]
    assert values[-2:] == [1.52, 1.48] and measured["n_measurements"] == len(values)
    assert measured["objective"] == pytest.approx(float(np.mean(values)))
    sem = float(np.std(values, ddof=1) / math.sqrt(len(values)))
    assert measured["objective_sem"] == pytest.approx(sem)
    cell = page.locator(f"tr[data-trial-id='{trial['id']}'] td.objective")
    expected = f"{fmt(measured['objective'])} ± {fmt(sem)}"
    cell.filter(has_text=expected).wait_for(timeout=10_000)
    plotted = page.evaluate(
        "(() => { const d = document.getElementById('best-plot').data[0];"
        " return {y: d.y, e: d.error_y.array}; })()"
    )
    assert plotted["y"] == pytest.approx([measured["objective"]])
    assert plotted["e"] == pytest.approx([sem])
    page.click("#audit-box summary")
    page.locator("#exp-audit-table td", has_text="trial.confirm").first.wait_for()
    page.screenshot(path=str(screenshots / "experiment_measured.png"), full_page=True)
    with page.expect_download() as download:
        page.click("#export-csv")
    csv_lines = Path(download.value.path()).read_text().strip().splitlines()
    assert len(csv_lines) == 2 and "objective" in csv_lines[0]

    # the trial page: full record, each source apart, a correction, trajectory, 3D replay
    # (a tracker's value, e.g. from a script, is shown apart and not averaged with the tape)
    api.add_measurements(trial["id"], [{"value": 3.0, "unit": "m", "source": "tracker"}])
    measured = api.get_trial(trial["id"])
    assert measured["objective"] == pytest.approx(float(np.mean(values)))
    page.goto(f"{server.url}/trials/{trial['id']}")
    page.wait_for_selector("#measurements-table td.m-value")
    assert page.locator("#measurements-table tbody tr").count() == len(measured["measurements"])
    page.locator("#sources-summary li[data-source='tape']").filter(
        has_text="makes the objective"
    ).wait_for()
    assert "not in the objective" in page.inner_text("#sources-summary li[data-source='tracker']")
    typo = next(m for m in measured["measurements"] if m["value"] == 1.52)
    row = page.locator(f"#measurements-table tr[data-measurement-id='{typo['id']}']")
    row.locator(".c-correct").click()
    row.locator(".c-value").fill("1,25")
    row.locator(".c-reason").fill("read the tape from the wrong end")
    row.locator(".c-save").click()
    row.locator(".c-error").filter(has_text="type the decimals after a point (1.25)").wait_for()
    row.locator(".c-value").fill("1.25")
    row.locator(".c-save").click()
    page.locator(f"#measurements-table tr.withdrawn[data-measurement-id='{typo['id']}']").wait_for()
    corrected = api.get_trial(trial["id"])
    counted = [
        m["value"]
        for m in corrected["measurements"]
        if m["source"] == "tape" and m["withdrawn_at"] is None
    ]
    assert sorted(counted) == sorted([1.50, 1.48, 1.25])
    assert corrected["objective"] == pytest.approx(float(np.mean(counted)))
    page.locator("#trial-facts").filter(has_text=fmt(corrected["objective"])).wait_for()
    page.screenshot(path=str(screenshots / "trial_corrected.png"), full_page=True)
    assert page.locator("#audit-table tbody tr").count() >= 3
    assert "trial.confirm" in page.inner_text("#audit-table")
    if measured["has_trajectory"]:
        page.wait_for_selector("#speed-plot .main-svg")
    page.click("#replay-button")
    page.wait_for_selector("#viz-frame", timeout=120_000)
    wait_for_drawn_arm(page)
    page.screenshot(path=str(screenshots / "trial.png"), full_page=True)
    page.click("#viz-close")

    # back on the experiment page: table and plot show the corrected objective, and the
    # next suggestion is made from the corrected data
    page.goto(f"{server.url}/experiments/{experiment_id}")
    sem = float(np.std(counted, ddof=1) / math.sqrt(len(counted)))
    cell = page.locator(f"tr[data-trial-id='{trial['id']}'] td.objective")
    cell.filter(has_text=f"{fmt(corrected['objective'])} ± {fmt(sem)}").wait_for()
    plotted = page.evaluate("document.getElementById('best-plot').data[0].y")
    assert plotted == pytest.approx([corrected["objective"]])
    page.click("#suggest-button")
    page.locator("#next-title").filter(has_text="trial 2").wait_for()
    model = api.model(experiment_id)
    assert model["incumbent_objective"] == pytest.approx(corrected["objective"])
    assert [t["index"] for t in api.list_trials(experiment_id)] == [1, 2]
    page.screenshot(path=str(screenshots / "experiment_corrected.png"), full_page=True)

    page.goto(f"{server.url}/experiments")
    page.wait_for_selector(f"tr[data-id='{experiment_id}'] td:has-text('1 / 20')")
    awaiting = page.locator(f"tr[data-id='{experiment_id}'] td[data-what='awaiting_confirmation']")
    assert awaiting.inner_text() == "1"
    page.screenshot(path=str(screenshots / "experiments.png"))


def test_viewer_sees_no_write_controls_and_cannot_forge_a_post(
    dashboard_server: Any, new_exp: Any, page: Any, screenshots: Path
) -> None:
    """A viewer sees the experiment but no write control; a forged post gets a 403."""
    server = dashboard_server
    api = server.client("operator")
    experiment = new_exp(
        api, name="viewer check", target="hardware", levels=5, method="bo-lei-default"
    )
    [trial] = api.suggest(experiment["id"])
    login(page, server, "viewer")
    page.goto(f"{server.url}/experiments/{experiment['id']}")
    page.wait_for_selector("#next-body:not([hidden])")
    page.wait_for_selector(f"tr[data-trial-id='{trial['id']}']")
    for selector in ("#suggest-button", "#exp-save", "#nav-new", "#attach-toggle"):
        assert not page.is_visible(selector), f"{selector} is visible to a viewer"
    for selector in ("#confirm-button", "#measure-form", "#fail-button", "#preview-button"):
        assert page.locator(selector).count() == 0, f"{selector} is on a viewer's page"
    assert page.is_visible("#replay-trial-button")
    assert page.is_visible("#export-csv")
    page.screenshot(path=str(screenshots / "experiment_viewer.png"), full_page=True)

    forged = page.evaluate(
        """async ([eid, tid, hash]) => {
            const token = localStorage.getItem("handful.token");
            const post = (path, body) => fetch(path, {method: "POST",
                headers: {"Authorization": `Bearer ${token}`, "Content-Type": "application/json",
                          "Idempotency-Key": "forged-1"},
                body: JSON.stringify(body)}).then(async r => [r.status, await r.text()]);
            return [await post(`/api/experiments/${eid}/suggest`, {n: 1}),
                    await post(`/api/trials/${tid}/confirm`, {schedule_hash: hash}),
                    await post(`/api/trials/${tid}/measurements`,
                               {repeats: [{value: 1.0, unit: "m/s"}]})];
        }""",
        [experiment["id"], trial["id"], trial["schedule_hash"]],
    )
    assert [status for status, _ in forged] == [403, 403, 403], forged
    after = api.get_trial(trial["id"])
    assert after["status"] == "awaiting_confirmation" and after["n_measurements"] == 0
    assert len(api.list_trials(experiment["id"])) == 1

    page.goto(f"{server.url}/experiments/new")
    page.wait_for_selector("text=only operators can create experiments")


def test_bad_measurements_fail_and_review_from_the_trial_page(
    dashboard_server_factory: Any, hw_exp: Any, page: Any, screenshots: Path
) -> None:
    """Text, NaN and a negative distance are refused, each with words on the page; failing
    needs a reason; a lost hardware lease's needs_review is resolved from the page."""
    server = dashboard_server_factory(HANDFUL_LEASE_SECONDS="1")
    api = server.client("operator")
    experiment = hw_exp(api, name="bad input", levels=5, n_initial=None, sim_preset="reference")
    trial, lost = api.suggest(experiment["id"], n=2)
    api.preview_and_confirm(trial)
    login(page, server, "operator")
    page.goto(f"{server.url}/trials/{trial['id']}")
    page.wait_for_selector("#measure-form")
    value = page.locator("input[aria-label='repeat 1 value']")
    for typed, words in (
        ("about two", "“about two” is not a number"),
        ("NaN", "“NaN” is not a number"),
        ("-2", "a distance cannot be negative"),
    ):
        value.fill(typed)
        page.click("#measure-save")
        error = page.locator("#measure-error")
        error.filter(has_text=words).wait_for(timeout=10_000)
        assert error.is_visible()
        assert "Not saved" in error.inner_text()
    page.screenshot(path=str(screenshots / "trial_bad_measurement.png"), full_page=True)
    assert api.get_trial(trial["id"])["n_measurements"] == 0

    # failing a trial needs a reason, in words; then it is failed with that reason
    page.click("#fail-button")
    page.locator("#reason-error").filter(has_text="Give a reason to mark failed").wait_for()
    assert api.get_trial(trial["id"])["status"] == "queued"
    page.fill("#reason-input", "cube slipped out of the gripper before the run")
    page.click("#fail-button")
    page.locator("#trial-status").filter(has_text="failed").wait_for()
    failed = api.get_trial(trial["id"])
    assert failed["status"] == "failed"
    assert failed["status_reason"] == "cube slipped out of the gripper before the run"
    assert page.locator("#measure-form").count() == 0

    # a worker claims the other trial and vanishes: its lease expires, a person decides
    api.preview_and_confirm(lost)
    [claim] = server.client("worker").claim("vanishing-worker", "hardware")
    assert claim["trial"]["id"] == lost["id"]
    deadline = time.monotonic() + 30
    while api.get_trial(lost["id"])["status"] != "needs_review" and time.monotonic() < deadline:
        time.sleep(0.3)
    assert api.get_trial(lost["id"])["status"] == "needs_review"
    page.goto(f"{server.url}/trials/{lost['id']}")
    page.wait_for_selector("#resolve-button")
    page.select_option("#resolve-decision", "requeue")
    page.fill("#reason-input", "tracker was unplugged; robot untouched, run it again")
    page.screenshot(path=str(screenshots / "trial_needs_review.png"), full_page=True)
    page.click("#resolve-button")
    # requeued on hardware means: back to the safety gate, a fresh confirmation needed
    page.locator("#trial-status").filter(has_text="awaiting confirmation").wait_for()
    assert api.get_trial(lost["id"])["status"] == "awaiting_confirmation"
    page.wait_for_selector("#confirm-button")
