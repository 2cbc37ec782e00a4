"""The driver plug-in interface: how a worker makes a robot run one pressure schedule.

A driver is the only code that touches the robot. The hardware worker hands it a schedule that
has already passed the safety gate (limits re-checked, confirmation hash matched); the driver
sends it, streams the tip tracking back, and reports what it actually executed and any fault.
See docs/DRIVERS.md for how a lab writes the driver for its own robot.
"""

from __future__ import annotations

import io
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np

N_CHAMBERS = 12


class DriverError(RuntimeError):
    """A driver could not be found, configured or connected."""


@dataclass(frozen=True)
class DriverCommand:
    """One trial for the robot, already checked by the hardware worker's gate.

    Attributes:
        trial_id: the server's trial id (for the driver's own logs).
        task: "tip_speed", "throw" or "hammer".
        pressure_schedule_pa: (H, 12) commanded chamber pressures, Pa; row t is held `step_s`.
        release_step: 1-based control step at whose end the gripper opens (throw), else None.
        step_s: seconds each row is held (5 s / H).
        nominal_pa: (12,) the resting pressures the robot starts from and vents back to, Pa.
        command_hold: "zero" (each row held for its step) or "linear" (ramped from the
            previous row over the step, from nominal at the start), as the experiment says.
    """

    trial_id: int
    task: str
    pressure_schedule_pa: np.ndarray
    release_step: int | None
    step_s: float
    nominal_pa: np.ndarray
    command_hold: str = "zero"

    @property
    def horizon(self) -> int:
        """H, the number of schedule rows."""
        return int(self.pressure_schedule_pa.shape[0])


@dataclass(frozen=True)
class TrackingSample:
    """One tip-tracker sample: time since the schedule started (s), position (m), velocity (m/s)."""

    time_s: float
    position_m: tuple[float, float, float]
    velocity_m_s: tuple[float, float, float]


@dataclass
class TipTracking:
    """The tip tracker's stream for one trial.

    Attributes:
        time_s: (T,) sample times since the schedule started, s.
        tip_pos_m: (T, 3) tip position in the robot base frame, m.
        tip_vel_m_s: (T, 3) tip velocity as the tracker reports it, m/s.
    """

    time_s: np.ndarray
    tip_pos_m: np.ndarray
    tip_vel_m_s: np.ndarray

    @classmethod
    def from_samples(cls, samples: list[TrackingSample]) -> TipTracking:
        """Stack streamed samples into arrays."""
        if not samples:
            return cls(np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3)))
        return cls(
            np.array([s.time_s for s in samples], dtype=np.float64),
            np.array([s.position_m for s in samples], dtype=np.float64),
            np.array([s.velocity_m_s for s in samples], dtype=np.float64),
        )

    @property
    def tip_speed_m_s(self) -> np.ndarray:
        """(T,) tracked tip speed, m/s."""
        return np.linalg.norm(self.tip_vel_m_s, axis=1) if len(self.time_s) else np.zeros(0)

    def to_npz_bytes(self) -> bytes:
        """Compressed npz with arrays time_s, tip_pos_m, tip_vel_m_s, tip_speed_m_s."""
        buf = io.BytesIO()
        np.savez_compressed(
            buf,
            time_s=self.time_s,
            tip_pos_m=self.tip_pos_m,
            tip_vel_m_s=self.tip_vel_m_s,
            tip_speed_m_s=self.tip_speed_m_s,
        )
        return buf.getvalue()


@dataclass
class Execution:
    """What the robot actually did for one command.

    Attributes:
        executed_pressure_schedule_pa: (H, 12) pressures the controller actually commanded, Pa.
            After a fault at step k the rows from k+1 on hold the nominal (vented) pressures.
        executed_release_step: the step at whose end the gripper actually opened, or None.
        tracking: the tip tracker's stream.
        fault: None, or one line saying what went wrong (an I2C fault, a lost tracker, ...).
        measured_objective: the driver's own measurement of the task objective when it has
            one (e.g. a throw distance); None for tip_speed, which the worker computes from
            `tracking`.
        info: JSON-able extras for the log (firmware, drift state, ...).
    """

    executed_pressure_schedule_pa: np.ndarray
    executed_release_step: int | None
    tracking: TipTracking
    fault: str | None = None
    measured_objective: float | None = None
    info: dict[str, Any] = field(default_factory=dict)


SampleCallback = Callable[[TrackingSample], None]


@runtime_checkable
class Driver(Protocol):
    """What a robot driver provides. Drivers are built by `load_driver(name, **options)`.

    A driver may also set `max_pressure_pa` (float): the robot's own ceiling, and `ceilings`
    (`app.policy.HardwareCeilings`: source pressure, maximum step, chamber maximum), checked
    by the worker's gate against the experiment's limits and the schedule whatever the server
    says: a claim beyond them never reaches `execute`.
    """

    name: str

    def execute(self, command: DriverCommand, on_sample: SampleCallback | None = None) -> Execution:
        """Run one schedule on the robot; stream tracking samples to `on_sample` as they come.

        Must return (not raise) on robot faults, with `Execution.fault` set and the schedule
        actually executed up to the fault. Raise only when the robot could not be reached.
        """
        ...

    def abort(self) -> None:
        """Stop the running schedule as soon as it is safe (vent to nominal). Thread-safe."""
        ...

    def close(self) -> None:
        """Release the robot connection."""
        ...
