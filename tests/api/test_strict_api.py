"""The API refuses what it cannot take with a 4xx, never a 500, and its OpenAPI document
says so (issue 16, findings 6 and 8): ids range-checked, strict numbers, validation errors
cut short, every error reply and media type declared."""

from __future__ import annotations

import httpx
import pytest

BIG = 2**63  # one past the largest row id


def _get(live_server, path, role="viewer"):
    headers = {"Authorization": f"Bearer {live_server.tokens[role]}"}
    return httpx.get(live_server.url + path, headers=headers, timeout=30)


def _post(live_server, path, body, role="operator"):
    headers = {"Authorization": f"Bearer {live_server.tokens[role]}"}
    return httpx.post(live_server.url + path, json=body, headers=headers, timeout=30)


@pytest.mark.parametrize(
    "path",
    [
        f"/api/experiments/{BIG}",
        f"/api/experiments/{BIG}/trials",
        f"/api/experiments/{BIG}/audit",
        f"/api/experiments/{BIG}/version",
        f"/api/experiments/{BIG}/model",
        f"/api/experiments/{BIG}/export",
        f"/api/trials/{BIG}",
        f"/api/trials/{BIG}/trajectory",
        f"/api/trials/{10**30}",
    ],
)
def test_ids_beyond_any_row_are_422_for_a_viewer(live_server, path):
    r = _get(live_server, path)
    assert r.status_code == 422, r.text
    assert r.json()["code"] == "validation_error"


def test_ids_beyond_any_row_on_writes(live_server):
    r = _post(live_server, f"/api/trials/{BIG}/fail", {"reason": "x"})
    assert r.status_code == 422
    r = _post(live_server, f"/api/experiments/{BIG}/suggest", {"n": 1})
    assert r.status_code == 422


@pytest.mark.parametrize(
    ("field", "value"),
    [("seed", False), ("seed", "3"), ("levels", 3.0), ("kappa", "0.5"), ("budget", True)],
)
def test_a_number_must_be_a_number(live_server, field, value):
    body = {"name": "strict", "task": "tip_speed", "levels": 3, "method": "random", field: value}
    r = _post(live_server, "/api/experiments", body)
    assert r.status_code == 422, r.text
    assert r.json()["detail"][0]["loc"] == ["body", field]


def test_measurement_values_are_strict_too(live_server, api):
    exp = api.create_experiment(name="strict", task="tip_speed", levels=3, method="random")
    [t] = api.suggest(exp["id"])
    r = httpx.post(
        f"{live_server.url}/api/trials/{t['id']}/measurements",
        json={"repeats": [{"value": "0.5", "unit": "m/s"}]},
        headers={
            "Authorization": f"Bearer {live_server.tokens['operator']}",
            "Idempotency-Key": "strict-1",
        },
        timeout=30,
    )
    assert r.status_code == 422 and r.json()["detail"][0]["loc"][-1] == "value"


def test_a_huge_validation_error_is_cut_short(live_server, api):
    exp = api.create_experiment(name="big", task="tip_speed", levels=3, method="random")
    bad = {"theta": ["x" * 100] * 10, "objective": "y" * 1000}  # 20,000 wrong numbers, 2 MB
    r = _post(live_server, f"/api/experiments/{exp['id']}/import", {"observations": [bad] * 2000})
    assert r.status_code == 422
    assert len(r.content) < 20_000
    detail = r.json()["detail"]
    assert len(detail) == 21 and "more problems" in detail[-1]["msg"]
    assert all(len(str(d.get("input", ""))) <= 201 for d in detail)


def test_a_body_that_is_not_json_is_a_documented_400(live_server):
    r = httpx.post(
        f"{live_server.url}/api/experiments",
        content=b"\xff\xfe not json",
        headers={
            "Authorization": f"Bearer {live_server.tokens['operator']}",
            "Content-Type": "application/json",
        },
        timeout=30,
    )
    assert r.status_code in (400, 422)
    assert set(r.json()) >= {"detail", "code"}


def test_the_openapi_document_declares_every_reply(live_server):
    spec = httpx.get(live_server.url + "/openapi.json").json()
    ops = [
        (path, method, op)
        for path, methods in spec["paths"].items()
        if path.startswith("/api")
        for method, op in methods.items()
    ]
    assert len(ops) > 20
    for path, method, op in ops:
        declared = set(op["responses"])
        assert {"401", "403", "404", "409", "413", "422", "503"} <= declared, (method, path)
    schemas = spec["components"]["schemas"]
    detail = schemas["ValidationErrorRead"]["properties"]["detail"]
    assert {"string", "array"} <= {alt.get("type") for alt in detail["anyOf"]}
    export = spec["paths"]["/api/experiments/{experiment_id}/export"]["get"]
    assert "text/csv" in export["responses"]["200"]["content"]
    traj = spec["paths"]["/api/trials/{trial_id}/trajectory"]["get"]
    assert "application/octet-stream" in traj["responses"]["200"]["content"]
    assert "503" in spec["paths"]["/health"]["get"]["responses"]
