"""The dashboard over HTTP (no browser): pages, local assets, and the 3D view route."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import httpx
import pytest

from app.dashboard import WEB_DIR, plotly_js_path
from app.policy import SIM_MAX_PRESSURE_PA
from app.service.lifecycle import STATUSES

LIMITS = {"nominal_pa": 100_000.0, "max_step_pa": 30_000.0, "source_pa": 205_000.0}


def test_no_asset_comes_from_another_host() -> None:
    """Templates, JS and CSS name no external URL (no CDN): everything is served here."""
    external = re.compile(r"""(src|href)\s*=\s*["']?(https?:)?//|@import\s+url\(["']?https?:""")
    for path in sorted(Path(WEB_DIR).rglob("*")):
        if path.suffix in {".html", ".js", ".css"}:
            text = path.read_text()
            assert not external.search(text), f"{path} loads something from another host"
            assert "cdn" not in text.lower(), f"{path} mentions a CDN"
    assert plotly_js_path().stat().st_size > 1_000_000


# What the pages' variables hold: the published schema they are read with.
JS_VARIABLES = {
    "t": "TrialDetail",
    "trial": "TrialDetail",
    "e": "ExperimentRead",
    "exp": "ExperimentRead",
    "experiment": "ExperimentRead",
    "job": "PreviewJobRead",
    "model": "ModelRead",
    "drift": "DriftRead",
}


def test_the_pages_read_only_fields_the_schemas_publish() -> None:
    """No page guesses a field name: every ``trial.x``, ``e.x``, ``job.x``... is a property of
    the schema the server publishes for that reply (``/api-schema.js`` serves them)."""
    from app.service import schemas

    wrong = []
    for path in sorted((Path(WEB_DIR) / "static" / "js").glob("*.js")):
        src = path.read_text().replace("e.g.", "")
        for var, name in JS_VARIABLES.items():
            model = getattr(schemas, name)
            fields = set(model.model_json_schema(mode="serialization")["properties"])
            for m in re.finditer(rf"(?<![\w.]){var}\??\.([A-Za-z_]\w*)", src):
                if m.group(1) not in fields:
                    wrong.append(f"{path.name}: {var}.{m.group(1)} is not in {name}")
    assert wrong == []


def test_pages_plotly_and_the_view_route(dashboard_server: Any) -> None:
    server = dashboard_server
    base = server.url
    for path in ("/login", "/experiments", "/experiments/new", "/experiments/1", "/trials/1"):
        r = httpx.get(base + path)
        assert r.status_code == 200 and r.headers["content-type"].startswith("text/html"), path
        for ref in re.findall(r'(?:src|href)="([^"]+)"', r.text):
            assert ref.startswith(("/", "data:")), f"{path} refers to {ref}"
            if ref.startswith("/static/") or ref.startswith("/vendor/"):
                assert httpx.get(base + ref).status_code == 200, ref
    assert httpx.get(base + "/", follow_redirects=False).headers["location"] == "/experiments"
    module = httpx.get(base + "/api-schema.js")
    assert module.headers["content-type"].startswith("text/javascript")
    consts = dict(re.findall(r"^export const (\w+) = (.*);$", module.text, re.MULTILINE))
    assert json.loads(consts["SIM_MAX_PRESSURE_PA"]) == SIM_MAX_PRESSURE_PA
    assert json.loads(consts["TRIAL_STATUSES"]) == list(STATUSES)
    assert json.loads(consts["RELEASE_TASKS"]) == ["throw"]
    assert "TrialRead" in json.loads(consts["SCHEMAS"])
    js = httpx.get(base + "/vendor/plotly.min.js")
    assert js.status_code == 200 and js.headers["content-type"].startswith("text/javascript")
    assert len(js.content) == plotly_js_path().stat().st_size

    status = httpx.get(base + "/viz/status").json()
    assert status["running"] is True
    viser_page = httpx.get(f"http://127.0.0.1:{status['port']}/")
    assert viser_page.status_code == 200 and '<div id="root">' in viser_page.text

    api = server.client("operator")
    exp = api.create_experiment(
        name="views", task="tip_speed", target="hardware", levels=3, limits=LIMITS
    )
    first, second = api.suggest(exp["id"], n=2)

    def view(role: str | None, body: dict[str, Any]) -> httpx.Response:
        headers = {"Authorization": f"Bearer {server.tokens[role]}"} if role else {}
        return httpx.post(base + "/viz/views", json=body, headers=headers, timeout=120.0)

    assert view(None, {"trial_id": first["id"]}).status_code == 401
    r = view("viewer", {})
    assert r.status_code == 422 and "trial_id is required" in r.json()["detail"]
    r = view("viewer", {"trial_id": 99_999})
    assert r.status_code == 404 and "99999" in r.json()["detail"]

    r = view("viewer", {"trial_id": first["id"], "overlay_trial_id": second["id"]})
    assert r.status_code == 200, r.text
    answer = r.json()
    assert answer["port"] == status["port"] and answer["websocket_path"] == f"/view/{answer['key']}"
    assert "simulated from its plan" in answer["label"]
    assert answer["overlay_label"].startswith(f"trial {second['index']} (overlay")

    job = api.preview(first["id"])
    done = api.wait_preview(job["job_id"])
    assert done["status"] == "done"
    r = view("operator", {"trial_id": second["id"], "preview_job_id": job["job_id"]})
    assert r.status_code == 422 and f"is of trial {first['id']}" in r.json()["detail"]
    r = view("operator", {"trial_id": first["id"], "preview_job_id": job["job_id"]})
    assert r.status_code == 200 and "sim preview" in r.json()["label"]
    r = view("operator", {"trial_id": first["id"], "preview_job_id": "no-such-job"})
    assert r.status_code == 404 and "no-such-job" in r.json()["detail"]


@pytest.mark.parametrize("bad", [{"trial_id": 0}, {"trial_id": "x"}])
def test_view_request_refuses_a_bad_trial_id(bad: dict[str, Any]) -> None:
    """The body model refuses nonsense before anything runs."""
    from pydantic import ValidationError

    from app.dashboard import ViewRequest

    with pytest.raises(ValidationError, match="trial_id"):
        ViewRequest.model_validate(bad)
