"""The hardware worker: one confirmed trial at a time, through a driver, behind a safety gate.

Same protocol as the sim worker (claim, heartbeat, result), one trial at a time. Before anything
moves, `app.workers.gate.gate_hardware_trial` re-checks the claimed schedule against the
experiment's limits and requires a confirmation whose hash equals `app.policy.schedule_hash` of
the schedule about to be sent; a trial that fails any check is reported as a fault and never
reaches the driver. The worker reports the schedule the driver says it actually executed.
"""

from __future__ import annotations

import logging
import math
import time
import uuid
from dataclasses import dataclass
from typing import Any

import numpy as np

from app.workers.common import (
    LeaseKeeper,
    PermanentError,
    StopFlag,
    StopRequested,
    default_worker_id,
    retry,
)
from app.workers.drivers.base import Driver, DriverCommand, Execution
from app.workers.gate import SafetyRefusal, gate_hardware_trial, predictions_line
from app.workers.objective import tip_speed_from_tracking
from app.workers.sim import _heartbeat_period

log = logging.getLogger("handful.worker.hardware")
#: longest time between heartbeats while a trial runs: how soon an operator's Stop reaches it
STOP_POLL_S = 1.0


@dataclass
class HardwareOutcome:
    """One claimed trial's fate: the result (`client.report_result` keywords) and what ran."""

    payload: dict[str, Any]
    command: DriverCommand | None
    execution: Execution | None


def execute_claim(driver: Driver, claim: dict[str, Any]) -> HardwareOutcome:
    """Gate, run and measure one claimed trial; build its result payload. No HTTP here.

    A refused trial never reaches the driver: its payload carries `fault` starting with
    "refused by the hardware worker" and no executed schedule.
    """
    trial, experiment = claim["trial"], claim["experiment"]
    base: dict[str, Any] = {"trajectory_npz": None, "summary": None}
    try:
        command = gate_hardware_trial(
            trial,
            experiment,
            trial_id=trial.get("id"),
            robot_max_pa=getattr(driver, "max_pressure_pa", None),
            robot_ceilings=getattr(driver, "ceilings", None),
        )
    except SafetyRefusal as exc:
        log.error("refused trial %s: %s", trial.get("id"), exc)
        return HardwareOutcome(
            {
                **base,
                "executed_pressure_schedule_pa": None,
                "executed_release_step": None,
                "objective": None,
                "fault": f"refused by the hardware worker: {exc}",
            },
            None,
            None,
        )
    log.info(
        "running trial %s on driver %s (%s)",
        command.trial_id,
        getattr(driver, "name", "?"),
        predictions_line(claim),
    )
    try:
        execution = driver.execute(command)
    except Exception as exc:
        log.exception("driver failed on trial %s", command.trial_id)
        return HardwareOutcome(
            {
                **base,
                "executed_pressure_schedule_pa": None,
                "executed_release_step": None,
                "objective": None,
                "fault": f"driver error, robot state unknown: {exc.__class__.__name__}: {exc}",
            },
            command,
            None,
        )
    objective: float | None = None
    fault = execution.fault
    if fault is None:
        if command.task == "tip_speed":
            try:
                objective = tip_speed_from_tracking(execution.tracking)
            except ValueError as exc:
                fault = f"tip speed not measurable: {exc}"
        else:
            objective = execution.measured_objective
    executed = np.asarray(execution.executed_pressure_schedule_pa, dtype=np.float64)
    return HardwareOutcome(
        {
            **base,
            "executed_pressure_schedule_pa": executed.tolist(),
            "executed_release_step": execution.executed_release_step,
            "objective": objective,
            "trajectory_npz": execution.tracking.to_npz_bytes()
            if len(execution.tracking.time_s)
            else None,
            "fault": fault,
            "summary": {"driver": getattr(driver, "name", "?"), **execution.info},
        },
        command,
        execution,
    )


class HardwareWorker:
    """Claims confirmed hardware trials one at a time and runs them through `driver`.

    Args:
        client: an `app.client` client holding a worker token.
        driver: the robot's driver (see `app.workers.drivers`).
        worker_id: name in the server's audit log.
        poll_s: longest pause between claims when nothing is confirmed.
    """

    def __init__(
        self,
        client: Any,
        driver: Driver,
        *,
        worker_id: str | None = None,
        poll_s: float = 1.0,
        heartbeat_s: float | None = None,
        stop: StopFlag | None = None,
    ) -> None:
        self.client = client
        self.driver = driver
        self.worker_id = worker_id or default_worker_id("hardware")
        self.poll_s = poll_s
        self.heartbeat_s = heartbeat_s
        self.stop = stop or StopFlag()
        self.stop.on_force.append(driver.abort)
        self.completed = 0
        self.faulted = 0

    def run_one(self, claim: dict[str, Any]) -> HardwareOutcome:
        """Run one claim with its lease heartbeated throughout; post its result."""
        # Heartbeat at least every STOP_POLL_S: a lease revoked by an operator's Stop (the
        # trial failed with a reason) is noticed within that time and the driver aborts
        # (vents to nominal).
        keeper = LeaseKeeper(
            lambda lid: self.client.heartbeat(lid),
            self.heartbeat_s or min(_heartbeat_period(claim), STOP_POLL_S),
            on_lost=lambda lid: self._stop_driver(lid),
        )
        keeper.add(claim["lease_id"])
        keeper.start()
        try:
            outcome = execute_claim(self.driver, claim)
        finally:
            keeper.stop()
        trial_id = claim["trial"]["id"]
        log.info(
            "ran trial %s lease %s objective %s fault %s",
            trial_id,
            claim["lease_id"],
            outcome.payload["objective"],
            outcome.payload["fault"],
        )
        try:
            retry(
                lambda: self.client.report_result(trial_id, claim["lease_id"], **outcome.payload),
                what=f"result {trial_id}",
            )
        except PermanentError as exc:
            log.error("result for trial %s refused: %s", trial_id, exc)
        if outcome.payload["fault"] is None:
            self.completed += 1
        else:
            self.faulted += 1
        return outcome

    def _stop_driver(self, lease_id: str) -> None:
        log.warning("lease %s revoked (trial stopped by an operator): aborting", lease_id)
        self.driver.abort()

    def run(self, *, max_trials: int | None = None, idle_exit_s: float | None = None) -> int:
        """Work until stopped (or `max_trials` run, or idle `idle_exit_s`); return trials run."""
        ran = 0
        idle_since = time.monotonic()
        delay = 0.05
        try:
            while not self.stop.is_set() and (max_trials is None or ran < max_trials):
                claim_id = uuid.uuid4().hex  # the same on every retry of this claim
                try:
                    claims = retry(
                        lambda cid=claim_id: self.client.claim(
                            worker_id=self.worker_id,
                            target="hardware",
                            max_trials=1,
                            claim_id=cid,
                        ),
                        what="claim",
                        stop=self.stop,
                        deadline_s=math.inf,
                    )
                except StopRequested:
                    break
                if not claims:
                    if idle_exit_s is not None and time.monotonic() - idle_since > idle_exit_s:
                        break
                    self.stop.wait(delay)
                    delay = min(self.poll_s, delay * 2.0)
                    continue
                delay = 0.05
                for claim in claims:
                    self.run_one(claim)
                    ran += 1
                idle_since = time.monotonic()
        finally:
            self.driver.close()
        return ran
