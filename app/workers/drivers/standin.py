"""`standin`: a faithful stand-in for the real arm, for tests, the demo and benchmarks.

It runs the MuJoCo simulator (`app.sim.rollout`) and then behaves like the lab's robot:

* **Tracking** like an HTC Vive tracker: about 90 Hz with timing jitter, millimetre position
  noise, velocity noise, and now and then a dropped sample. The tip-speed objective is computed
  by the worker from this noisy stream, never from the simulator's internal velocity.
* **A reality gap** (``gap``, 0 = none): the stand-in's own physical parameters are drawn, once
  per ``instance`` seed, from ranges around the simulator's (``GAP_RANGES``, ``instance_params``),
  so "hardware" and simulator disagree as a real arm and its model do.
* **Drift** across trials: a slowly wandering per-chamber pressure bias (the rest pose moves)
  and a wandering stiffness scale, which with ``wear_per_trial`` > 0 also sinks with use
  (wear). The drift is seeded and kept in a small JSON state file, so it continues where it
  left off when the worker restarts.
* **Faults** like the real robot's: an I2C fault becomes likely once the tip goes faster than
  `fault_speed_m_s` (the paper's fast runs broke electronics), and the tracker is lost now and
  then. After a fault the controller vents to nominal and the trial is reported as faulted.
* **Throw and hammer scores** are left to the operator's tape measure, as on the real robot;
  with `-o tape_measure=true` the stand-in plays that person too (simulated score ± 2 %), for
  unattended demos and benchmarks.

The driver never learns its own drift: it reports the schedule it was told to run (the
controller tracks commanded pressures), exactly like the real robot would.

The gap's ranges (at ``gap=1``; ``gap`` scales every half-width linearly, ``gap=0`` gives the
simulator's parameters exactly, i.e. the stand-in as it was before the gap existed). Which
facts of ``shared/ROBOT.md`` they rest on, and where they are judgement:

* bending stiffness of each joint ×(1 ± 0.25), damping ×(1 ± 0.30): ROBOT.md gives one lumped
  k and c per joint (136/27/27 N·m/rad, 7.5/2/2 N·m·s/rad) for bellows of plastic chambers and
  says the real arm changes with "wear, hysteresis, temperature"; lumped values identified for
  a simulator are rarely better than a few tens of percent on such an arm (judgement).
* pressure time constant of each joint ×(1 ± 0.30): ROBOT.md's 0.2/0.5/0.8 s first-order lags
  stand for valves, tubing and controller; the real controller "tracks each commanded chamber
  pressure", its lag is not measured (judgement).
* link masses ×(1 ± 0.10): ROBOT.md's link masses (3.881, 3.474 kg) come with "the links' true
  shapes are CAD meshes", so they are CAD estimates; cables and fittings add or miss mass.
* tip load 0 … 0.15 kg: the simulated tip-speed arm is bare (ROBOT.md: "No object"), but the
  real one carries the HTC Vive tracker the tip is tracked with (ROBOT.md, hardware limits);
  0.15 kg covers a tracker and its mount (judgement; the tracker's mass is not in ROBOT.md).
* dry friction of each joint's bending 0 … 0.5 % of its stiffness × 1 rad (0.68 / 0.135 /
  0.135 N·m): ROBOT.md names hysteresis; the simulator has none (judgement on the size).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import os
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from app.policy import SIM_MAX_PRESSURE_PA, HardwareCeilings
from app.workers.drivers.base import (
    DriverCommand,
    DriverError,
    Execution,
    SampleCallback,
    TipTracking,
    TrackingSample,
)

if TYPE_CHECKING:  # the simulator is imported when the stand-in first runs
    from app.sim import ArmParams

log = logging.getLogger(__name__)

#: relative half-widths at gap = 1 (multiplicative: value × (1 + gap·half·u), u ~ U(−1, 1))
GAP_RANGES: dict[str, float] = {
    "stiffness": 0.25,
    "damping": 0.30,
    "time_constant": 0.30,
    "link_mass": 0.10,
}
#: absolute ranges at gap = 1 (value = gap·top·u, u ~ U(0, 1))
GAP_TIP_LOAD_KG = 0.15
GAP_FRICTION_PER_STIFFNESS = 0.005  # N·m of dry friction per N·m/rad of bending stiffness
MAX_GAP = 2.0


def instance_params(gap: float, instance: int) -> tuple[ArmParams, dict[str, Any]]:
    """The stand-in robot ``instance``'s own ArmParams for reality gap ``gap`` (0..MAX_GAP), and
    what was drawn (JSON-safe: per-joint factors, link mass factors, tip load, friction).

    A pure function of (gap, instance): the same instance is the same robot in every process.
    ``gap=0`` returns the simulator's ``ArmParams()`` exactly. Each draw is one U(−1, 1) (or
    U(0, 1)) number per parameter from a generator seeded by ``instance`` alone, scaled by
    ``gap``, so one instance at a larger gap is the same robot further from the simulator."""
    from app.sim import ArmParams

    base = ArmParams()
    gap = float(gap)
    if not (math.isfinite(gap) and 0.0 <= gap <= MAX_GAP):
        raise DriverError(f"standin gap={gap!r} must lie in [0, {MAX_GAP:g}]")
    rng = np.random.default_rng([0x9A9, int(instance) & 0xFFFFFFFF])
    u = {
        "stiffness": rng.uniform(-1.0, 1.0, 3),
        "damping": rng.uniform(-1.0, 1.0, 3),
        "time_constant": rng.uniform(-1.0, 1.0, 3),
        "link_mass": rng.uniform(-1.0, 1.0, 2),
        "friction": rng.uniform(0.0, 1.0, 3),
        "tip_load": rng.uniform(0.0, 1.0),
    }
    drawn: dict[str, Any] = {"gap": gap, "instance": int(instance)}
    if gap == 0.0:
        return base, {**drawn, "nominal": True}
    f = {k: 1.0 + gap * GAP_RANGES[k] * np.asarray(u[k]) for k in GAP_RANGES}
    joints = tuple(
        dataclasses.replace(
            j,
            stiffness_nm_rad=j.stiffness_nm_rad * f["stiffness"][i],
            damping_nms_rad=j.damping_nms_rad * f["damping"][i],
            time_constant_s=j.time_constant_s * f["time_constant"][i],
            frictionloss_nm=gap
            * GAP_FRICTION_PER_STIFFNESS
            * j.stiffness_nm_rad
            * float(u["friction"][i]),
        )
        for i, j in enumerate(base.joints)
    )
    links = tuple(
        dataclasses.replace(lk, mass_kg=lk.mass_kg * f["link_mass"][i])
        for i, lk in enumerate(base.links)
    )
    tip_load = gap * GAP_TIP_LOAD_KG * float(u["tip_load"])
    params = dataclasses.replace(base, joints=joints, links=links, tip_load_kg=tip_load)
    drawn.update(
        {k: [round(float(v), 6) for v in f[k]] for k in GAP_RANGES},
        friction_nm=[round(j.frictionloss_nm, 6) for j in joints],
        tip_load_kg=round(tip_load, 6),
    )
    return params, drawn


def _as_bool(value: str | bool) -> bool:
    if isinstance(value, bool):
        return value
    v = str(value).strip().lower()
    if v in {"1", "true", "yes", "on"}:
        return True
    if v in {"0", "false", "no", "off"}:
        return False
    raise DriverError(f"expected true/false, got {value!r}")


def _as_float(
    name: str, value: str | float, *, lo: float = -math.inf, hi: float = math.inf
) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise DriverError(f"standin option {name}={value!r} is not a number") from None
    if not (math.isfinite(x) and lo <= x <= hi):
        raise DriverError(f"standin option {name}={value!r} must lie in [{lo:g}, {hi:g}]")
    return x


@dataclass
class DriftState:
    """The stand-in's slow drift, persisted between trials and worker restarts.

    Attributes:
        seed: seeds every random draw (with the trial counter).
        n_trials: trials run so far on this stand-in robot.
        pressure_bias_pa: (12,) unobserved offset between commanded and actual pressure, Pa.
        stiffness_scale: multiplies the joints' bending stiffness (1.0 = as built).
    """

    seed: int
    n_trials: int
    pressure_bias_pa: list[float]
    stiffness_scale: float

    @classmethod
    def fresh(cls, seed: int) -> DriftState:
        """A new robot: no bias, nominal stiffness."""
        return cls(seed=seed, n_trials=0, pressure_bias_pa=[0.0] * 12, stiffness_scale=1.0)

    @classmethod
    def load(cls, path: Path, seed: int) -> DriftState:
        """Read the state file, or start fresh when there is none."""
        if not path.exists():
            return cls.fresh(seed)
        try:
            raw = json.loads(path.read_text())
            state = cls(
                seed=int(raw["seed"]),
                n_trials=int(raw["n_trials"]),
                pressure_bias_pa=[float(v) for v in raw["pressure_bias_pa"]],
                stiffness_scale=float(raw["stiffness_scale"]),
            )
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise DriverError(f"standin state file {path} is unreadable: {exc}") from None
        if len(state.pressure_bias_pa) != 12:
            raise DriverError(f"standin state file {path}: pressure_bias_pa needs 12 values")
        return state

    def save(self, path: Path) -> None:
        """Write atomically (temp file + rename), so a crash never leaves half a file."""
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".standin-", suffix=".json")
        with os.fdopen(fd, "w") as fh:
            json.dump(self.__dict__, fh, indent=1)
        os.replace(tmp, path)


class StandinDriver:
    """The simulator dressed up as the real robot. Options arrive as strings (CLI).

    Args:
        seed: seeds drift, noise and faults (with the persisted trial counter).
        state_file: JSON file holding the drift state; "" keeps it in memory only.
        preset: simulator preset ("reference" or "fast").
        realtime: stream tracking at wall-clock pace (a 5 s schedule takes 5 s), like the robot.
        tracker_hz: tracker sample rate, Hz (Vive: about 90).
        position_noise_m: σ of tracked position noise, m.
        velocity_noise_m_s: σ of tracked velocity noise, m/s.
        dropout: probability that one tracker sample is lost.
        bias_step_pa: σ of the per-trial random step of each chamber's pressure bias, Pa.
        stiffness_step: σ of the per-trial random step of the stiffness scale.
        fault_speed_m_s: tip speed above which I2C faults become likely, m/s.
        fault_probability: chance of an I2C fault for a run that reaches 1 m/s above that speed.
        tracker_loss_probability: chance per trial that the tracker is lost mid-run.
        gap: size of the reality gap (0: the simulator's parameters; 1: ``GAP_RANGES``).
        instance: seeds this robot's physical parameters (default: ``seed``).
        wear_per_trial: how far the stiffness scale's resting value sinks per trial (0: none;
            1e-4: 10 % lower after 1000 trials, bounded at 0.85).
    """

    name = "standin"
    max_pressure_pa = 205_000.0  # the lab's supply: nothing above it can reach the chambers
    #: the paper robot's: 205 kPa supply, 30 kPa offsets, chambers rated 40 psi
    ceilings = HardwareCeilings(source_pa=205_000.0, max_step_pa=30_000.0)

    def __init__(
        self,
        seed: str | int = 0,
        state_file: str = "data/standin_state.json",
        preset: str = "reference",
        realtime: str | bool = False,
        tracker_hz: str | float = 90.0,
        position_noise_m: str | float = 1.0e-3,
        velocity_noise_m_s: str | float = 0.03,
        dropout: str | float = 0.003,
        bias_step_pa: str | float = 250.0,
        stiffness_step: str | float = 0.004,
        fault_speed_m_s: str | float = 2.0,
        fault_probability: str | float = 0.5,
        tracker_loss_probability: str | float = 0.01,
        tape_measure: str | bool = False,
        gap: str | float = 0.0,
        instance: str | int | None = None,
        wear_per_trial: str | float = 0.0,
    ) -> None:
        try:
            self.seed = int(seed)
        except (TypeError, ValueError):
            raise DriverError(f"standin option seed={seed!r} is not an integer") from None
        self.preset = str(preset)
        self.realtime = _as_bool(realtime)
        # Off by default, as on the real robot: a person measures throws and hits with a tape
        # and enters the numbers. On: the stand-in plays that person (unattended demos, benches).
        self.tape_measure = _as_bool(tape_measure)
        self.tracker_hz = _as_float("tracker_hz", tracker_hz, lo=1.0, hi=2000.0)
        self.position_noise_m = _as_float("position_noise_m", position_noise_m, lo=0.0, hi=0.1)
        self.velocity_noise_m_s = _as_float("velocity_noise_m_s", velocity_noise_m_s, lo=0, hi=5)
        self.dropout = _as_float("dropout", dropout, lo=0.0, hi=0.5)
        self.bias_step_pa = _as_float("bias_step_pa", bias_step_pa, lo=0.0, hi=10_000.0)
        self.stiffness_step = _as_float("stiffness_step", stiffness_step, lo=0.0, hi=0.1)
        self.fault_speed_m_s = _as_float("fault_speed_m_s", fault_speed_m_s, lo=0.0)
        self.fault_probability = _as_float("fault_probability", fault_probability, lo=0, hi=1)
        self.tracker_loss_probability = _as_float(
            "tracker_loss_probability", tracker_loss_probability, lo=0.0, hi=1.0
        )
        self.gap = _as_float("gap", gap, lo=0.0, hi=MAX_GAP)
        try:
            self.instance = self.seed if instance in (None, "") else int(instance)  # type: ignore[arg-type]
        except (TypeError, ValueError):
            raise DriverError(f"standin option instance={instance!r} is not an integer") from None
        self.wear_per_trial = _as_float("wear_per_trial", wear_per_trial, lo=0.0, hi=0.01)
        self._params: Any = None  # this instance's ArmParams, drawn on first use
        self.gap_draw: dict[str, Any] = {}
        self.state_path = Path(state_file) if state_file else None
        self.state = (
            DriftState.load(self.state_path, self.seed)
            if self.state_path is not None
            else DriftState.fresh(self.seed)
        )
        self._abort = threading.Event()
        self._lock = threading.Lock()

    # --- drift ------------------------------------------------------------------------------
    def _advance_drift(self) -> tuple[np.ndarray, float, np.random.Generator]:
        """Step the drift one trial (mean-reverting random walk); persist; return this trial's."""
        s = self.state
        rng = np.random.default_rng([s.seed, s.n_trials])
        bias = 0.98 * np.asarray(s.pressure_bias_pa) + rng.normal(0.0, self.bias_step_pa, 12)
        # mean-reverting to 1, or with wear to a resting value that sinks with use
        rest = max(1.0 - self.wear_per_trial * s.n_trials, 0.85)
        stiffness = rest + 0.98 * (s.stiffness_scale - rest) + rng.normal(0.0, self.stiffness_step)
        stiffness = float(np.clip(stiffness, 0.85, 1.15))
        s.pressure_bias_pa = [float(v) for v in bias]
        s.stiffness_scale = stiffness
        s.n_trials += 1
        if self.state_path is not None:
            s.save(self.state_path)  # before the run: a crash mid-trial still wore the robot
        return bias, stiffness, rng

    def instance_params(self) -> ArmParams:
        """This robot's own ArmParams before drift (``instance_params(gap, instance)``)."""
        if self._params is None:
            self._params, self.gap_draw = instance_params(self.gap, self.instance)
        return self._params

    def _sim_params(self, stiffness_scale: float) -> Any:
        """This instance's ArmParams with every joint's bending stiffness scaled by the drift."""
        base = self.instance_params()
        joints = tuple(
            dataclasses.replace(j, stiffness_nm_rad=j.stiffness_nm_rad * stiffness_scale)
            for j in base.joints
        )
        return dataclasses.replace(base, joints=joints)

    # --- tracking ---------------------------------------------------------------------------
    def _track(
        self, time_s: np.ndarray, pos: np.ndarray, vel: np.ndarray, rng: np.random.Generator
    ) -> TipTracking:
        """Sample the true tip motion like a Vive tracker: jittered ~90 Hz, noisy, with drops."""
        t_end = float(time_s[-1])
        n = math.floor(t_end * self.tracker_hz) + 1
        period = 1.0 / self.tracker_hz
        t = np.arange(n) * period + rng.uniform(0.0, 0.1 * period, n)
        t = np.clip(t, 0.0, t_end)
        keep = rng.random(n) >= self.dropout
        t = t[keep]
        p = np.stack([np.interp(t, time_s, pos[:, k]) for k in range(3)], axis=1)
        v = np.stack([np.interp(t, time_s, vel[:, k]) for k in range(3)], axis=1)
        p = p + rng.normal(0.0, self.position_noise_m, p.shape)
        v = v + rng.normal(0.0, self.velocity_noise_m_s, v.shape)
        return TipTracking(t, p, v)

    # --- the Driver interface ----------------------------------------------------------------
    def execute(self, command: DriverCommand, on_sample: SampleCallback | None = None) -> Execution:
        """Run the schedule on the simulated arm, then stream and report like the robot."""
        from app.sim import SimulationDiverged, rollout

        with self._lock:
            self._abort.clear()
            commanded = np.asarray(command.pressure_schedule_pa, dtype=np.float64)
            nominal = np.asarray(command.nominal_pa, dtype=np.float64)
            bias, stiffness, rng = self._advance_drift()
            actual = np.clip(commanded + bias[None, :], 0.0, SIM_MAX_PRESSURE_PA)
            info: dict[str, Any] = {
                "driver": self.name,
                "robot_trial": self.state.n_trials,
                "seed": self.seed,
            }
            try:
                res = rollout(
                    command.task,
                    actual,
                    release_step=command.release_step,
                    preset=self.preset,
                    record_hz=4.0 * self.tracker_hz,
                    params=self._sim_params(stiffness),
                    command_hold=command.command_hold,
                )
            except SimulationDiverged as exc:
                return Execution(
                    executed_pressure_schedule_pa=np.broadcast_to(nominal, commanded.shape).copy(),
                    executed_release_step=None,
                    tracking=TipTracking.from_samples([]),
                    fault=f"controller fault at start: {exc}",
                    info=info,
                )
            traj = res.trajectory
            tracking = self._track(traj.time_s, traj.tip_pos_m, traj.tip_vel_m_s, rng)

            fault: str | None = None
            fault_time = math.inf
            true_speed = np.asarray(traj.tip_speed_m_s)
            over = true_speed - self.fault_speed_m_s
            if over.max() > 0.0:
                p_fault = self.fault_probability * min(1.0, float(over.max()))
                if rng.random() < p_fault:
                    fault_time = float(traj.time_s[int(np.argmax(over > 0.0))])
                    fault = (
                        f"I2C fault at t={fault_time:.2f} s (tip at {true_speed.max():.2f} m/s): "
                        "pressure controller lost its sensors, vented to nominal"
                    )
            if fault is None and rng.random() < self.tracker_loss_probability:
                fault_time = float(rng.uniform(0.5, float(traj.time_s[-1])))
                fault = f"tracker lost at t={fault_time:.2f} s (occlusion / base station)"

            keep = tracking.time_s <= fault_time
            tracking = TipTracking(
                tracking.time_s[keep], tracking.tip_pos_m[keep], tracking.tip_vel_m_s[keep]
            )
            delivered = self._stream(tracking, on_sample)
            if delivered < len(tracking.time_s):
                fault = "aborted by the worker; vented to nominal"
                fault_time = float(tracking.time_s[delivered - 1]) if delivered else 0.0
                tracking = TipTracking(
                    tracking.time_s[:delivered],
                    tracking.tip_pos_m[:delivered],
                    tracking.tip_vel_m_s[:delivered],
                )

            executed = commanded.copy()
            release = command.release_step
            if fault is not None:
                done_steps = math.ceil(fault_time / command.step_s - 1e-9)
                executed[max(done_steps, 0) :] = nominal
                if release is not None and release > done_steps:
                    release = None
            measured = None
            if self.tape_measure and fault is None and command.task != "tip_speed":
                # A person measures throws/hits by hand: a few percent of scatter.
                measured = float(res.objective * (1.0 + rng.normal(0.0, 0.02)))
            info["stiffness_scale"] = stiffness
            if self.gap:
                info["gap"] = self.gap_draw
            info["pressure_bias_rms_pa"] = float(np.sqrt(np.mean(bias**2)))
            return Execution(
                executed_pressure_schedule_pa=executed,
                executed_release_step=release,
                tracking=tracking,
                fault=fault,
                measured_objective=measured,
                info=info,
            )

    def _stream(self, tracking: TipTracking, on_sample: SampleCallback | None) -> int:
        """Hand samples to the callback, at wall-clock pace when realtime; return how many."""
        start = time.monotonic()
        for i in range(len(tracking.time_s)):
            if self.realtime:
                delay = start + float(tracking.time_s[i]) - time.monotonic()
                if delay > 0 and self._abort.wait(delay):
                    return i
            if self._abort.is_set():
                return i
            if on_sample is not None:
                on_sample(
                    TrackingSample(
                        float(tracking.time_s[i]),
                        tuple(float(x) for x in tracking.tip_pos_m[i]),  # type: ignore[arg-type]
                        tuple(float(x) for x in tracking.tip_vel_m_s[i]),  # type: ignore[arg-type]
                    )
                )
        return len(tracking.time_s)

    def abort(self) -> None:
        """Stop streaming; the running trial ends as an aborted fault."""
        self._abort.set()

    def close(self) -> None:
        """Nothing to release."""
