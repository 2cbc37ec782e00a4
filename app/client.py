"""An httpx client over handful's HTTP API (tests, workers and scripts use it).

    from app.client import HandfulClient
    with HandfulClient("http://127.0.0.1:8000", token="hf_...") as api:
        exp = api.create_experiment(name="tip speed", task="tip_speed", levels=5)
        [trial] = api.suggest(exp["id"], n=1)
        api.add_measurements(trial["id"], [{"value": 3.1, "unit": "m/s"}])

Every method returns the decoded JSON (dicts/lists, fields as in docs/ARCHITECTURE.md) and
raises ``HandfulAPIError`` (status, detail, code) for any 4xx/5xx reply.
"""

from __future__ import annotations

import base64
import random
import time
import uuid
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import httpx
import numpy as np

JSON = dict[str, Any]


class HandfulAPIError(Exception):
    """An error reply from the server: HTTP ``status``, its ``detail`` text and ``code``."""

    def __init__(self, status: int, detail: Any, code: str | None = None, body: Any = None) -> None:
        self.status = status
        self.detail = detail
        self.code = code
        self.body = body  # the decoded error reply, e.g. a duplicate's ``receipt``
        super().__init__(f"HTTP {status}: {detail}")


class HandfulClient:
    """Typed wrapper of every route. ``retries`` re-sends idempotent calls on connection errors.

    Args:
        base_url: e.g. ``http://127.0.0.1:8000``.
        token: API token (``handful token create NAME`` or ``login``).
        timeout: seconds per request.
        retries: how many times to retry a GET, heartbeat, result or keyed measurement post
            after a connection error (server restarting), with backoff.
        busy_deadline_s: a 503 ``database_busy`` (nothing was stored) is retried, any
            method, waiting what its ``Retry-After`` says (at least an exponential backoff
            with jitter), until this many seconds have passed since the first try; 0: never.
    """

    def __init__(
        self,
        base_url: str,
        token: str | None = None,
        *,
        timeout: float = 60.0,
        retries: int = 0,
        busy_deadline_s: float = 60.0,
        transport: httpx.BaseTransport | None = None,
    ) -> None:
        self.base_url = base_url.rstrip("/")
        self.retries = retries
        self.busy_deadline_s = busy_deadline_s
        self._http = httpx.Client(base_url=self.base_url, timeout=timeout, transport=transport)
        self.token = token

    # --- plumbing -------------------------------------------------------------------------------
    @property
    def token(self) -> str | None:
        return self._token

    @token.setter
    def token(self, value: str | None) -> None:
        self._token = value
        if value:
            self._http.headers["Authorization"] = f"Bearer {value}"
        else:
            self._http.headers.pop("Authorization", None)

    def close(self) -> None:
        self._http.close()

    def __enter__(self) -> HandfulClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def request(
        self,
        method: str,
        path: str,
        *,
        json: Any = None,
        params: dict[str, Any] | None = None,
        headers: dict[str, str] | None = None,
        idempotent: bool | None = None,
        raw: bool = False,
    ) -> Any:
        """Send one request; decode JSON (or return the Response when ``raw``)."""
        deadline = time.monotonic() + self.busy_deadline_s
        busy = 0
        while True:
            r = self._send(
                method, path, json=json, params=params, headers=headers, idempotent=idempotent
            )
            wait = self._busy_wait(r, busy, deadline)
            if wait is None:
                break
            busy += 1
            time.sleep(wait)
        if r.status_code >= 400:
            try:
                body = r.json()
                detail, code = body.get("detail", body), body.get("code")
            except ValueError:
                body, detail, code = None, r.text, None
            raise HandfulAPIError(r.status_code, detail, code, body)
        if raw:
            return r
        if r.status_code == 204 or not r.content:
            return None
        if r.headers.get("content-type", "").startswith("application/json"):
            return r.json()
        return r.text

    def _send(
        self,
        method: str,
        path: str,
        *,
        json: Any,
        params: dict[str, Any] | None,
        headers: dict[str, str] | None,
        idempotent: bool | None,
    ) -> httpx.Response:
        """One request, re-sent after connection errors when it is safe (``retries``)."""
        retry = (method == "GET") if idempotent is None else idempotent
        attempts = 1 + (self.retries if retry else 0)
        for i in range(attempts):
            try:
                return self._http.request(method, path, json=json, params=params, headers=headers)
            except (
                httpx.ConnectError,
                httpx.ReadError,
                httpx.RemoteProtocolError,
                httpx.ConnectTimeout,
            ):
                if i == attempts - 1:
                    raise
                time.sleep(min(0.25 * 2**i, 5.0))
        raise AssertionError("unreachable")

    @staticmethod
    def _busy_wait(r: httpx.Response, n_before: int, deadline: float) -> float | None:
        """Seconds to wait before re-sending a request the database was too busy for (503
        ``database_busy``: nothing was stored), or None: do not retry."""
        if r.status_code != 503:
            return None
        try:
            if r.json().get("code") != "database_busy":
                return None
        except (ValueError, AttributeError):
            return None
        try:
            after = float(r.headers.get("Retry-After", "1"))
        except ValueError:
            after = 1.0
        backoff = min(0.1 * 2**n_before, 5.0) * (0.5 + random.random())
        wait = max(after, backoff)
        left = deadline - time.monotonic()
        if left <= 0:
            return None
        return min(wait, left)

    # --- health & auth --------------------------------------------------------------------------
    def health(self) -> JSON:
        """``{status, db, version}``."""
        return self.request("GET", "/health")

    def rotate_token(self) -> JSON:
        """Swap this client's token for a new one (the old one is revoked at once)."""
        out = self.request("POST", "/api/auth/rotate")
        self.token = out["token"]
        return out

    def login(self, username: str, password: str) -> JSON:
        """Log in; the client then uses the returned token."""
        out = self.request(
            "POST", "/api/auth/login", json={"username": username, "password": password}
        )
        self.token = out["token"]
        return out

    def me(self) -> JSON:
        return self.request("GET", "/api/me")

    # --- experiments ----------------------------------------------------------------------------
    def create_experiment(self, **fields: Any) -> JSON:
        """Create an experiment; fields as ExperimentCreate (name, task, target, levels, ...)."""
        return self.request("POST", "/api/experiments", json=fields)

    def list_experiments(self) -> list[JSON]:
        return self.request("GET", "/api/experiments")

    def get_experiment(self, experiment_id: int) -> JSON:
        return self.request("GET", f"/api/experiments/{experiment_id}")

    def patch_experiment(self, experiment_id: int, **fields: Any) -> JSON:
        """Change status / notes / budget."""
        return self.request("PATCH", f"/api/experiments/{experiment_id}", json=fields)

    def list_trials(self, experiment_id: int, status: str | None = None) -> list[JSON]:
        params = {"status": status} if status else None
        return self.request("GET", f"/api/experiments/{experiment_id}/trials", params=params)

    def suggest(self, experiment_id: int, n: int = 1) -> list[JSON]:
        """Ask the optimiser for n new trials."""
        return self.request("POST", f"/api/experiments/{experiment_id}/suggest", json={"n": n})

    def suggest_timed(self, experiment_id: int, n: int = 1) -> tuple[list[JSON], dict[str, float]]:
        """``suggest`` plus the server's timings in ms (``optimizer``, ``total``)."""
        r = self.request(
            "POST", f"/api/experiments/{experiment_id}/suggest", json={"n": n}, raw=True
        )
        timings = {}
        for part in r.headers.get("server-timing", "").split(","):
            name, _, dur = part.strip().partition(";dur=")
            if name and dur:
                timings[name] = float(dur)
        return r.json(), timings

    def attach_trial(self, experiment_id: int, theta: Sequence[float], note: str = "") -> JSON:
        """Add a trial with a chosen θ (D,)."""
        body = {"theta": [float(v) for v in theta], "note": note}
        return self.request("POST", f"/api/experiments/{experiment_id}/trials", json=body)

    def export(self, experiment_id: int, format: str = "json") -> Any:
        """JSON dict, or CSV text with ``format="csv"``."""
        return self.request(
            "GET", f"/api/experiments/{experiment_id}/export", params={"format": format}
        )

    def import_observations(self, experiment_id: int, observations: Sequence[JSON]) -> list[JSON]:
        """Import ``[{theta, objective, objective_sem?, unit?, note?}]`` as completed trials."""
        return self.request(
            "POST",
            f"/api/experiments/{experiment_id}/import",
            json={"observations": list(observations)},
        )

    def model(self, experiment_id: int) -> JSON:
        """Lengthscales, incumbent and posterior slices."""
        return self.request("GET", f"/api/experiments/{experiment_id}/model")

    def drift(self, experiment_id: int) -> JSON:
        """The drift check: the reference's scores, the band, the warning."""
        return self.request("GET", f"/api/experiments/{experiment_id}/drift")

    def set_reference(self, experiment_id: int, **fields: Any) -> JSON:
        """Schedule a reference θ: ``every`` (k ≥ 2), ``theta_from`` (incumbent | trial),
        ``trial_index``, ``baseline_n``, ``tolerance``; returns the drift check."""
        return self.request("PUT", f"/api/experiments/{experiment_id}/reference", json=fields)

    def stop_reference(self, experiment_id: int) -> JSON:
        """Stop scheduling reference trials."""
        return self.request("DELETE", f"/api/experiments/{experiment_id}/reference")

    def audit(self, experiment_id: int, limit: int = 500) -> list[JSON]:
        return self.request(
            "GET", f"/api/experiments/{experiment_id}/audit", params={"limit": limit}
        )

    def version(self, experiment_id: int) -> int:
        """The experiment's change counter."""
        return int(self.request("GET", f"/api/experiments/{experiment_id}/version")["version"])

    # --- sim prior and sim twins ---------------------------------------------------------------
    def sim_prior(self, experiment_id: int) -> JSON:
        """The linked sim experiment, its scored and pending trials, the twins' preset."""
        return self.request("GET", f"/api/experiments/{experiment_id}/sim-prior")

    def link_sim_prior(self, experiment_id: int, sim_experiment_id: int) -> JSON:
        """Link a hardware experiment to a sim experiment (same task, policy, hold)."""
        return self.request(
            "PUT",
            f"/api/experiments/{experiment_id}/sim-prior",
            json={"sim_experiment_id": sim_experiment_id},
        )

    def unlink_sim_prior(self, experiment_id: int) -> JSON:
        return self.request("DELETE", f"/api/experiments/{experiment_id}/sim-prior")

    def start_sim_prior(self, experiment_id: int, **fields: Any) -> JSON:
        """Create and link a sim experiment with ``n_trials`` queued trials (SimPriorStartIn)."""
        return self.request(
            "POST", f"/api/experiments/{experiment_id}/sim-prior/start", json=fields
        )

    def experiment_twins(self, experiment_id: int) -> list[JSON]:
        """Each trial beside its sim twin and the discrepancy (hardware − twin)."""
        return self.request("GET", f"/api/experiments/{experiment_id}/twins")

    def trial_twins(self, trial_id: int) -> list[JSON]:
        return self.request("GET", f"/api/trials/{trial_id}/twins")

    def wait_twin(
        self, trial_id: int, kind: str = "planned", *, timeout_s: float = 60.0, poll_s: float = 0.2
    ) -> JSON:
        """Poll until the trial's sim twin of ``kind`` is stored (TimeoutError after
        ``timeout_s``)."""
        deadline = time.monotonic() + timeout_s
        while True:
            found = [t for t in self.trial_twins(trial_id) if t["kind"] == kind]
            if found:
                return found[0]
            if time.monotonic() > deadline:
                raise TimeoutError(f"trial {trial_id} has no {kind} sim twin after {timeout_s} s")
            time.sleep(poll_s)

    # --- trials ---------------------------------------------------------------------------------
    def get_trial(self, trial_id: int) -> JSON:
        """A trial with its measurements and audit trail."""
        return self.request("GET", f"/api/trials/{trial_id}")

    def add_measurements(
        self, trial_id: int, repeats: Sequence[JSON], *, idempotency_key: str | None = None
    ) -> JSON:
        """Post raw repeats ``[{value, unit, note}]``; a random Idempotency-Key if none given.

        Returns the receipt: ``{trial_id, experiment_id, status, objective, objective_sem,
        n_measurements, stored}`` (``stored``: the repeats this post stored). On a retry after
        a lost connection a 409 ``duplicate_request`` means the first post was stored: its
        receipt is returned then.
        """
        key = idempotency_key or uuid.uuid4().hex
        path = f"/api/trials/{trial_id}/measurements"
        body = {"repeats": list(repeats)}
        try:
            return self.request(
                "POST", path, json=body, headers={"Idempotency-Key": key}, idempotent=True
            )
        except HandfulAPIError as exc:
            if exc.code == "duplicate_request" and idempotency_key is None:
                receipt = (exc.body or {}).get("receipt")
                if receipt is not None:
                    return receipt
            raise

    def withdraw_measurement(self, measurement_id: int, reason: str) -> JSON:
        """Withdraw a repeat (kept, no longer counted); returns the trial's new objective."""
        return self.request(
            "POST", f"/api/measurements/{measurement_id}/withdraw", json={"reason": reason}
        )

    def supersede_measurement(
        self, measurement_id: int, value: float, unit: str, reason: str, note: str = ""
    ) -> JSON:
        """Correct a repeat (the old one kept, withdrawn); returns the trial's new objective."""
        body = {"value": value, "unit": unit, "reason": reason, "note": note}
        return self.request("POST", f"/api/measurements/{measurement_id}/supersede", json=body)

    def fail_trial(self, trial_id: int, reason: str) -> JSON:
        return self.request("POST", f"/api/trials/{trial_id}/fail", json={"reason": reason})

    def abandon_trial(self, trial_id: int, reason: str) -> JSON:
        return self.request("POST", f"/api/trials/{trial_id}/abandon", json={"reason": reason})

    def resolve_trial(self, trial_id: int, decision: str, reason: str) -> JSON:
        """decision: requeue | fail | complete | abandon (needs_review trials)."""
        return self.request(
            "POST", f"/api/trials/{trial_id}/resolve", json={"decision": decision, "reason": reason}
        )

    def confirm_trial(self, trial_id: int, schedule_hash: str) -> JSON:
        """Confirm a hardware trial's schedule (its ``schedule_hash``)."""
        return self.request(
            "POST", f"/api/trials/{trial_id}/confirm", json={"schedule_hash": schedule_hash}
        )

    def preview_and_confirm(self, trial: JSON, *, timeout_s: float = 120.0) -> JSON:
        """An operator's two steps for a hardware trial: preview its schedule (waiting for the
        rollout to finish), then confirm exactly that schedule. Returns the confirmed trial."""
        job = self.wait_preview(self.preview(trial["id"])["job_id"], timeout_s=timeout_s)
        if job["status"] != "done":
            raise HandfulAPIError(409, f"preview failed: {job['error']}", "preview_failed")
        return self.confirm_trial(trial["id"], job["schedule_hash"])

    def run_trial(self, trial_id: int) -> JSON:
        """Simulate a queued sim trial in the service; returns the finished trial."""
        return self.request("POST", f"/api/trials/{trial_id}/run")

    def preview(self, trial_id: int) -> JSON:
        """Start a preview; returns ``{job_id, status, progress, ...}``."""
        return self.request("POST", f"/api/trials/{trial_id}/preview")

    def get_preview(self, job_id: str) -> JSON:
        return self.request("GET", f"/api/previews/{job_id}")

    def wait_preview(self, job_id: str, *, timeout_s: float = 120.0, poll_s: float = 0.2) -> JSON:
        """Poll a preview until done or error (TimeoutError after ``timeout_s``)."""
        deadline = time.monotonic() + timeout_s
        while True:
            job = self.get_preview(job_id)
            if job["status"] in ("done", "error"):
                return job
            if time.monotonic() > deadline:
                raise TimeoutError(f"preview {job_id} still {job['status']} after {timeout_s} s")
            time.sleep(poll_s)

    def trajectory(self, trial_id: int) -> JSON:
        """The trial's trajectory arrays as lists."""
        return self.request("GET", f"/api/trials/{trial_id}/trajectory")

    def trajectory_npz(self, trial_id: int) -> bytes:
        """The trial's trajectory .npz bytes."""
        r = self.request(
            "GET", f"/api/trials/{trial_id}/trajectory", params={"format": "npz"}, raw=True
        )
        return r.content

    # --- workers --------------------------------------------------------------------------------
    def claim(
        self, worker_id: str, target: str, max_trials: int = 1, *, claim_id: str | None = None
    ) -> list[JSON]:
        """``[{lease_id, trial, experiment, lease_expires_at}]`` (maybe empty).

        ``claim_id``: the caller's id for this claim, the same on each retry of it (then the
        call is safe to retry: a retry whose first try was stored returns that try's leases).
        """
        body: JSON = {"worker_id": worker_id, "target": target, "max_trials": max_trials}
        if claim_id is not None:
            body["claim_id"] = claim_id
        return self.request(
            "POST", "/api/workers/claim", json=body, idempotent=claim_id is not None
        )

    def heartbeat(self, lease_id: str) -> JSON:
        """Extend a lease; HandfulAPIError 409 (code lease_lost) when it was lost."""
        return self.request("POST", f"/api/leases/{lease_id}/heartbeat", idempotent=True)

    def report_result(
        self,
        trial_id: int,
        lease_id: str,
        *,
        executed_pressure_schedule_pa: Any = None,
        executed_release_step: int | None = None,
        objective: float | None = None,
        trajectory_npz: bytes | str | Path | None = None,
        fault: str | None = None,
        summary: JSON | None = None,
    ) -> JSON:
        """Report a leased trial's result (idempotent per lease: safe to retry)."""
        traj_b64 = None
        if trajectory_npz is not None:
            raw = (
                trajectory_npz
                if isinstance(trajectory_npz, bytes)
                else Path(trajectory_npz).read_bytes()
            )
            traj_b64 = base64.b64encode(raw).decode()
        sched = None
        if executed_pressure_schedule_pa is not None:
            sched = np.asarray(executed_pressure_schedule_pa, dtype=np.float64).tolist()
        body = {
            "lease_id": lease_id,
            "executed_pressure_schedule_pa": sched,
            "executed_release_step": executed_release_step,
            "objective": None if objective is None else float(objective),
            "trajectory_npz_b64": traj_b64,
            "fault": fault,
            "summary": summary,
        }
        return self.request("POST", f"/api/trials/{trial_id}/result", json=body, idempotent=True)
