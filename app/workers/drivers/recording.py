"""`recording`: a flight recorder in front of another driver.

Every command that reaches it is appended to a JSON-lines file (before it is passed on), then the
inner driver runs it. Labs use it to audit exactly what reached the robot; the safety tests use it
to prove that nothing unconfirmed or beyond the limits ever does.

    handful worker hardware ... --driver recording -o inner=standin -o log=commands.jsonl \
        -o inner.preset=fast

Options starting with ``inner.`` are passed to the inner driver without the prefix.
"""

from __future__ import annotations

import json
import os
import threading
import time
from pathlib import Path
from typing import Any

from app.workers.drivers.base import Driver, DriverCommand, DriverError, Execution, SampleCallback


class RecordingDriver:
    """Log each command to `log` (JSON lines, fsynced), then delegate to the `inner` driver."""

    name = "recording"

    def __init__(self, inner: str = "standin", log: str = "", **options: str) -> None:
        from app.workers.drivers import load_driver

        if not log:
            raise DriverError("recording driver needs -o log=PATH (a JSON-lines file)")
        if inner == "recording":
            raise DriverError("recording driver cannot wrap itself")
        unknown = [k for k in options if not k.startswith("inner.")]
        if unknown:
            raise DriverError(
                f"recording driver: unknown option(s) {', '.join(sorted(unknown))}; "
                "inner driver options are given as inner.KEY=VALUE"
            )
        inner_options = {k.removeprefix("inner."): v for k, v in options.items()}
        self.inner: Driver = load_driver(inner, **inner_options)
        self.max_pressure_pa: float | None = getattr(self.inner, "max_pressure_pa", None)
        self.ceilings = getattr(self.inner, "ceilings", None)
        self.log_path = Path(log)
        self.log_path.parent.mkdir(parents=True, exist_ok=True)
        self._lock = threading.Lock()
        self.commands: list[DriverCommand] = []

    def _record(self, command: DriverCommand) -> None:
        entry: dict[str, Any] = {
            "wall_time": time.time(),
            "trial_id": command.trial_id,
            "task": command.task,
            "pressure_schedule_pa": command.pressure_schedule_pa.tolist(),
            "release_step": command.release_step,
            "step_s": command.step_s,
            "nominal_pa": command.nominal_pa.tolist(),
        }
        with self._lock, self.log_path.open("a") as fh:
            fh.write(json.dumps(entry) + "\n")
            fh.flush()
            os.fsync(fh.fileno())
        self.commands.append(command)

    def execute(self, command: DriverCommand, on_sample: SampleCallback | None = None) -> Execution:
        """Record the command, then run it on the inner driver."""
        self._record(command)
        return self.inner.execute(command, on_sample)

    def abort(self) -> None:
        """Abort the inner driver."""
        self.inner.abort()

    def close(self) -> None:
        """Close the inner driver."""
        self.inner.close()


def read_log(path: str | Path) -> list[dict[str, Any]]:
    """All commands a recording driver logged, oldest first."""
    p = Path(path)
    if not p.exists():
        return []
    return [json.loads(line) for line in p.read_text().splitlines() if line.strip()]
