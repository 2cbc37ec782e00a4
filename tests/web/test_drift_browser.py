"""The drift chart in Chromium: reference trials run on the stand-in robot (its real worker,
drifting) and the experiment page's chart gains each one once it is scored.

``run_until_reference_scored`` is the reusable step: give it a page open on a hardware
experiment with a reference schedule, an operator's client, and a hardware worker running;
it asks for suggestions (confirming each trial as an operator would) until a reference trial
is made, waits for the worker to score it, and checks the page's drift chart shows it.
``standin_worker`` starts the real ``handful worker hardware --driver standin``.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.web.test_dashboard_browser import login

REPO = Path(__file__).resolve().parents[2]
LIMITS = {"nominal_pa": 100_000.0, "max_step_pa": 30_000.0, "source_pa": 205_000.0}
#: a stand-in that drifts visibly (its pressure bias and stiffness wander in larger steps,
#: the stiffness sinks with wear) and never faults (a faulted trial needs a person's review)
DRIFTING = {
    "seed": "3",
    "state_file": "",
    "preset": "fast",
    "bias_step_pa": "10000",
    "stiffness_step": "0.05",
    "wear_per_trial": "0.01",
    "fault_probability": "0",
    "tracker_loss_probability": "0",
}


@contextlib.contextmanager
def standin_worker(
    server: Any, folder: Path, options: dict[str, str] | None = None
) -> Iterator[subprocess.Popen[bytes]]:
    """``handful worker hardware --driver standin -o KEY=VALUE ...`` on ``server`` (its own
    process group, killed on exit; its log in ``folder/standin-worker.log``)."""
    token_file = folder / "standin-worker.token"
    token_file.write_text(server.tokens["worker"] + "\n")
    token_file.chmod(0o600)
    opts = [a for k, v in (options or DRIFTING).items() for a in ("-o", f"{k}={v}")]
    cmd = [sys.executable, "-m", "app.cli", "worker", "hardware", "--server", server.url]
    cmd += ["--token-file", str(token_file), "--poll", "0.2", "--driver", "standin", *opts]
    with open(folder / "standin-worker.log", "wb") as log:
        proc = subprocess.Popen(
            cmd,
            cwd=REPO,
            stdout=log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
            env={**os.environ, "PYTHONUNBUFFERED": "1"},
        )
    try:
        yield proc
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=30)


_PLOTTED = """() => {
  const node = document.querySelector('#drift-plot');
  const trace = node && node.data && node.data.find((d) => d.name.startsWith('reference'));
  return trace ? Array.from(trace.x) : [];
}"""


def drift_chart_indices(page: Any) -> list[int]:
    """The trial numbers of the references the page's drift chart plots."""
    return list(page.evaluate(_PLOTTED))


def run_until_reference_scored(
    page: Any, api: Any, experiment_id: int, *, timeout_s: float = 180.0
) -> dict:
    """Suggest (one at a time), preview and confirm every trial made, and wait for the
    running hardware worker to finish them, until a reference trial is scored; then wait for
    the page's drift chart (the page is open on the experiment) to plot it, and for its
    warning to agree with the server's verdict. Returns the reference trial."""
    deadline = time.monotonic() + timeout_s
    while True:
        made = api.suggest(experiment_id)
        for t in made:
            api.preview_and_confirm(t)
        for t in made:
            while (now := api.get_trial(t["id"]))["status"] in ("queued", "running"):
                assert time.monotonic() < deadline, f"trial {t['index']} did not finish in time"
                time.sleep(0.2)
            assert now["status"] == "completed" and now["objective"] is not None, (
                f"trial {now['index']} ended {now['status']}: {now['status_reason']}"
            )
        refs = [t for t in made if t["source"] == "reference"]
        if refs:
            break
        assert time.monotonic() < deadline, "no reference trial was scheduled in time"
    ref = api.get_trial(refs[0]["id"])
    page.wait_for_function(
        f"() => ({_PLOTTED})().includes({ref['index']})", timeout=int(timeout_s * 1000)
    )
    drift = api.drift(experiment_id)
    assert drift_chart_indices(page) == [p["index"] for p in drift["points"]]
    warning = page.locator("#drift-warning")
    if drift["shifted"]:
        warning.filter(has_text=f"reference trial {drift['points'][-1]['index']} scored").wait_for()
    else:
        warning.wait_for(state="hidden")
    return ref


@pytest.mark.slow
def test_the_drift_chart_follows_the_reference_on_the_drifting_standin(
    dashboard_server: Any, page: Any, screenshots: Path, tmp_path: Path
):
    server = dashboard_server
    api = server.client("operator")
    exp = api.create_experiment(
        name="drift on the stand-in",
        task="tip_speed",
        target="hardware",
        levels=3,
        method="random",
        seed=4,
        sim_preset="fast",
        limits=LIMITS,
    )
    login(page, server, "operator")
    page.goto(f"{server.url}/experiments/{exp['id']}")
    # the operator schedules the check on the page: k = 1 is refused in words, k = 2 taken
    page.locator("#drift-status").filter(has_text="No drift check scheduled").wait_for()
    page.fill("#drift-every", "1")
    page.click("#drift-save")
    page.locator("#exp-error").filter(
        has_text="“1” is not a whole number of trials of 2"
    ).wait_for()
    assert api.get_experiment(exp["id"])["reference"] is None
    page.fill("#drift-every", "2")
    page.fill("#drift-m", "2")
    page.click("#drift-save")
    page.locator("#drift-status").filter(has_text="every 2 hardware trials").wait_for()
    assert api.get_experiment(exp["id"])["reference"]["baseline_n"] == 2
    assert drift_chart_indices(page) == []
    with standin_worker(server, tmp_path):
        first = run_until_reference_scored(page, api, exp["id"])
        assert page.locator("#drift-status").filter(has_text="1 reference scored").count() == 1
        second = run_until_reference_scored(page, api, exp["id"])
        # two references: the band is drawn (a shaded rectangle and its centre line)
        page.wait_for_function(
            "() => (document.querySelector('#drift-plot').layout.shapes || []).length === 2"
        )
        third = run_until_reference_scored(page, api, exp["id"])
    assert first["theta"] == second["theta"] == third["theta"]  # the frozen incumbent
    assert [first["index"], second["index"], third["index"]] == [2, 4, 6]  # every 2nd trial
    # the same θ, yet the robot drifted (and the tracker is noisy): no two scores alike
    assert len({first["objective"], second["objective"], third["objective"]}) == 3
    # the operator narrows the band below the third's shift: the page warns, the log says so
    drift = api.drift(exp["id"])
    shift = abs(third["objective"] - drift["band"]["center"])
    page.fill("#drift-tolerance", f"{shift / 2:.6f}")
    page.click("#drift-save")
    page.locator("#drift-warning").filter(
        has_text=f"reference trial {third['index']} scored"
    ).wait_for()
    [entry] = [a for a in api.audit(exp["id"]) if a["action"] == "drift.shift"]
    assert entry["trial_id"] == third["id"]
    page.locator("#drift-card").screenshot(path=str(screenshots / "drift_chart.png"))
