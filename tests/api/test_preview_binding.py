"""Confirming a hardware trial is bound to that operator's finished preview of its exact
schedule: the server records each preview (who, when, hash, hold) and refuses the rest."""

from __future__ import annotations

from app.client import HandfulClient
from app.db.session import Database
from app.service.auth import add_user, create_token


def preview(api, trial_id: int) -> dict:
    job = api.wait_preview(api.preview(trial_id)["job_id"])
    assert job["status"] == "done", job
    return job


def test_confirm_needs_this_operators_preview_of_this_schedule(error_of, hw_exp, live_server, api):
    # tip speed, random search (a hardware experiment measured by the tracker)
    exp = hw_exp(api, task="tip_speed", method="random", n_initial=None, objective_unit=None)
    a, b = api.suggest(exp["id"], n=2)
    # never previewed: refused, whatever hash the client sends, and it says why
    err = error_of(api.confirm_trial, a["id"], a["schedule_hash"])
    assert err.status == 409 and err.code == "not_previewed", err.detail
    assert "not previewed" in err.detail and f"#{a['index']}" in err.detail
    # a preview of another trial (the 3D card still showing the last one) does not count
    preview(api, b["id"])
    err = error_of(api.confirm_trial, a["id"], a["schedule_hash"])
    assert err.code == "not_previewed", err.detail
    # another operator's preview does not count for this one
    db = Database(live_server.db_url)
    try:
        with db.write() as s:
            add_user(s, "olivia", "operator", password="correct horse battery")
            token = create_token(s, "olivia")
    finally:
        db.dispose()
    with HandfulClient(live_server.url, token) as olivia:
        job = preview(olivia, a["id"])
        assert job["schedule_hash"] == a["schedule_hash"]
        err = error_of(api.confirm_trial, a["id"], a["schedule_hash"])
        assert err.code == "not_previewed", err.detail
        assert api.get_trial(a["id"])["status"] == "awaiting_confirmation"
        # the one who previewed may confirm
        t = olivia.confirm_trial(a["id"], a["schedule_hash"])
    assert t["status"] == "queued" and t["confirmed_by"] == "olivia"
    detail = api.get_trial(a["id"])
    [p] = detail["previews"]
    assert (p["previewed_by"], p["schedule_hash"]) == ("olivia", a["schedule_hash"])
    assert p["previewed_at"] <= detail["confirmed_at"]
    actions = [x["action"] for x in detail["audit"]]
    assert actions.index("trial.preview") < actions.index("trial.confirm")
    # b was previewed by this operator: confirmed
    assert api.confirm_trial(b["id"], b["schedule_hash"])["status"] == "queued"
