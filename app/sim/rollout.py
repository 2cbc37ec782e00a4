"""One episode: a pressure schedule in, a trajectory record and the task objective out.

Stepping happens in C: ``mujoco.mj_step(model, data, nstep=k)`` runs between sampling points
(the recording grid, the fixed 100 Hz objective grid and the control-step ends), split as
``mj_step2`` / ``mj_step`` / ``mj_step1`` so that the sensors (world-frame tip and object
position and velocity) describe the state exactly at each point; Python only copies arrays
there. The dynamics are the same whatever ``record_hz`` is.

**Command hold** (``command_hold``), how row t of the schedule is applied during control step t
(ROBOT.md, "The published simulator, exactly"):

* ``"zero"``: held for the whole step, from t = 0 (row 1 from the first physics step).
* ``"linear"``: ramped linearly from the previous row to row t over the step's physics steps
  (the first physics step repeats the previous command, the last applies row t), starting
  from all-zero pressures and an open gripper at reset; row t is reached only at the step's end.
  Python sets the command before each physics step (``mj_step`` one step at a time).

The throw's gripper command is part of the command vector: closed for steps 1..t_R, open
after, ramped like the chambers under ``"linear"``. Any command above ``GRIP_CLOSED_FROM`` of
full scale is fully closed, so under ``"linear"`` the gripper closes from the second physics
step and opens only in the last physics step of step t_R + 1 (never for t_R = H), as in the
published simulator. Under ``"zero"`` it opens at the end of step t_R.

**Objectives** (``objective_rule``), with H control steps of 5 s / H each, all read at the
control steps' ends:

* ``"paper"``, the formulas as printed:
  ``throw``: Σ_{t=1}^{t_R} ‖tip velocity_t‖ + ‖cube centre‖ at 5 s (the cube's distance from
  the robot base's footprint centre, the world origin). ``hammer``: (Σ_{t=1}^{H} m·|ż_t| + F_t −
  1[t ≥ 0.7H]·‖x_t − g‖) / 1000, with ż_t and x_t the ball centre's world-vertical velocity and
  position, m the ball mass, g the plate centre, and F_t the plate's touch reading at the end of
  step t (the normal contact force inside the plate's sensor volume during the last physics step
  of control step t), as in the published code: impacts between step ends do not count.
* ``"published"``, what the published code computes with its release time set to 0.5·t_R s
  (its float-time quirks reproduced by step index): ``throw``: the tip speeds of steps
  1..t_R − 1, plus step t_R itself when 3 ≤ t_R ≤ H − 1, never step H's, plus the distance of
  the cube's body origin (``CubeParams.origin_offset_m`` from its centre, towards the palm) from
  the world origin. ``hammer``: per step (m·|v_z| + F − d) / 1000 with v_z the tip velocimeter's
  z component in the tip's own frame, d the distance from the plate centre to the tip site
  (not the ball), counted for steps t > 0.7H (steps 8..10 of 10).
* ``tip_speed`` (both rules): the largest tip speed on the 100 Hz grid (every 10 ms) over 5 s.

Both rules are computed for every episode (``RolloutResult.objective_by_rule``); ``objective``
is the chosen one's.
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from app.policy import (
    EPISODE_S,
    N_CHAMBERS,
    OBJECTIVE_RULES,
    RELEASE_TASKS,
    PolicyError,
    check_command_hold,
    check_objective_rule,
    check_release_step,
    check_schedule,
)
from app.sim.model import (
    CUBE_BODY,
    CUBE_ORIGIN_SENSOR,
    EEF_LINVEL_SENSOR,
    EEF_POS_SENSOR,
    EEF_VEL_SENSOR,
    GRIP_ACTUATOR,
    GRIP_WELD,
    HAMMER_BODY,
    OBJECT_LINVEL_SENSOR,
    OBJECT_POS_SENSOR,
    PAD_SENSORS,
    PLATE_SENSOR,
    build_model,
    check_task,
    effective_params,
    hinge_joint_name,
)
from app.sim.params import ArmParams
from app.sim.presets import Preset, get_preset

OBJECTIVE_HZ = 100.0  # the tip-speed grid of `max_tip_speed` and `tip_speed_100hz`
BEND_LIMIT_FRACTION = 0.995  # a hinge within 0.5 % of its range end counts as at its limit
MAX_PLAUSIBLE_SPEED_M_S = 1000.0


class SimulationDiverged(RuntimeError):
    """The physics blew up (MuJoCo rejected the state, or it became non-finite or absurd)."""

    def __init__(self, message: str, *, task: str, preset: str, time_s: float) -> None:
        super().__init__(message)
        self.task = task
        self.preset = preset
        self.time_s = time_s

    def __reduce__(self) -> tuple[Any, ...]:
        # picklable, so it crosses from a pool's worker process intact
        return (_rebuild_diverged, (str(self), self.task, self.preset, self.time_s))


def _rebuild_diverged(message: str, task: str, preset: str, time_s: float) -> SimulationDiverged:
    return SimulationDiverged(message, task=task, preset=preset, time_s=time_s)


_TRAJ_FIELDS = (
    "time_s",
    "tip_pos_m",
    "tip_vel_m_s",
    "tip_speed_m_s",
    "object_pos_m",
    "plate_force_n",
    "pressure_pa",
    "bend_rad",
)


@dataclass
class Trajectory:
    """An episode sampled at ``record_hz`` (T samples, t = 0 included).

    Attributes:
        time_s: (T,) sample times, s.
        tip_pos_m: (T, 3) end-effector site position, world frame, m.
        tip_vel_m_s: (T, 3) end-effector linear velocity, world frame, m/s.
        tip_speed_m_s: (T,) its norm, m/s.
        object_pos_m: (T, 3) cube / hammer-ball centre, m; zeros when the task has no object.
        plate_force_n: (T,) force-plate touch reading, N; zeros without a plate.
        pressure_pa: (T, 12) chamber pressure states (actuator activations), Pa.
        bend_rad: (T, 3, 2) per continuum joint its (u, v) bend: the sums of its x / y hinges.
        qpos: (T, nq) MuJoCo positions for 3D replay, or None unless asked for.
    """

    time_s: np.ndarray
    tip_pos_m: np.ndarray
    tip_vel_m_s: np.ndarray
    tip_speed_m_s: np.ndarray
    object_pos_m: np.ndarray
    plate_force_n: np.ndarray
    pressure_pa: np.ndarray
    bend_rad: np.ndarray
    qpos: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.time_s.shape[0])

    def to_npz(self, path: str | Path) -> None:
        """Write the arrays to a compressed ``.npz`` (``qpos`` only when recorded)."""
        arrays = {name: getattr(self, name) for name in _TRAJ_FIELDS}
        if self.qpos is not None:
            arrays["qpos"] = self.qpos
        with open(path, "wb") as fh:
            np.savez_compressed(fh, **arrays)

    @classmethod
    def from_npz(cls, path: str | Path) -> Trajectory:
        """Read a trajectory written by ``to_npz``; ValueError if a field is missing."""
        with np.load(path, allow_pickle=False) as npz:
            missing = [name for name in _TRAJ_FIELDS if name not in npz.files]
            if missing:
                raise ValueError(f"{path}: not a trajectory file, missing {', '.join(missing)}")
            arrays = {name: np.array(npz[name]) for name in _TRAJ_FIELDS}
            qpos = np.array(npz["qpos"]) if "qpos" in npz.files else None
        return cls(**arrays, qpos=qpos)


@dataclass
class RolloutResult:
    """What one episode gives: the objective, summary numbers and the trajectory.

    Attributes:
        task, preset: what ran.
        objective: the task objective (module docstring).
        max_tip_speed: largest tip speed on the 100 Hz grid, m/s.
        tip_speed_100hz: (501,) tip speed every 10 ms from t = 0, m/s.
        wall_s: wall-clock time of the simulation, s.
        bend_limit_hits: continuum joints (0..2) with a hinge at its range end at any sample.
        release_step: the 1-based release step (throw), else None.
        peak_plate_force_n: largest plate reading at any sample (hammer), else 0.
        objective_terms: the objective's parts (per task), for inspection.
        trajectory: the recorded trajectory.
        command_hold: how each row was applied ("zero" or "linear").
        objective_rule: which scoring rule ``objective`` follows ("paper" or "published").
        objective_by_rule: the objective under every rule, same episode.
        cube_lost_before_release: throw with the friction grasp: whether the pads lost the
            cube before the release step's end (it slipped out); False with the weld; else None.
        last_pad_contact_s: throw, friction grasp: last 100 Hz sample with a pad touching the
            cube (s); None when it never touched or without pads.
    """

    task: str
    preset: str
    objective: float
    max_tip_speed: float
    tip_speed_100hz: np.ndarray
    wall_s: float
    bend_limit_hits: list[int]
    release_step: int | None
    peak_plate_force_n: float
    objective_terms: dict[str, float]
    trajectory: Trajectory
    timestep_s: float = 0.0
    n_disks: int = 0
    command_hold: str = "zero"
    objective_rule: str = "paper"
    objective_by_rule: dict[str, float] = field(default_factory=dict)
    cube_lost_before_release: bool | None = None
    last_pad_contact_s: float | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    def to_summary(self) -> dict[str, Any]:
        """JSON-able summary (no trajectory arrays except the 100 Hz tip speed)."""
        final_obj = self.trajectory.object_pos_m[-1]
        return {
            "task": self.task,
            "preset": self.preset,
            "command_hold": self.command_hold,
            "objective_rule": self.objective_rule,
            "objective": float(self.objective),
            "objective_by_rule": {k: float(v) for k, v in self.objective_by_rule.items()},
            "max_tip_speed": float(self.max_tip_speed),
            "tip_speed_100hz": [round(float(v), 6) for v in self.tip_speed_100hz],
            "wall_s": float(self.wall_s),
            "release_step": self.release_step,
            "bend_limit_hits": list(self.bend_limit_hits),
            "peak_plate_force_n": float(self.peak_plate_force_n),
            "plate_hit": bool(self.peak_plate_force_n >= 5.0),
            "final_object_pos_m": [float(v) for v in final_obj],
            "objective_terms": {k: float(v) for k, v in self.objective_terms.items()},
            "timestep_s": self.timestep_s,
            "n_disks": self.n_disks,
            "cube_lost_before_release": self.cube_lost_before_release,
            "last_pad_contact_s": self.last_pad_contact_s,
        }


@functools.lru_cache(maxsize=16)
def compiled_model(task: str, preset: Preset, params: ArmParams) -> mujoco.MjModel:
    """The model a rollout uses, compiled once per process (memoised; never modify it)."""
    return build_model(task, preset, params)


@dataclass(frozen=True)
class _Layout:
    """Addresses in the model that a rollout reads (sensor addresses are −1 when absent)."""

    eef_pos: int
    eef_linvel: int
    eef_vel_local: int
    cube_origin: int
    pads: tuple[int, ...]
    grip_actuator: int
    object_pos: int
    object_linvel: int
    plate: int
    weld: int
    hinge_qposadr: np.ndarray  # (3, 2, n−1)
    hinge_limit: np.ndarray  # (3, 2, n−1)
    object_mass_kg: float


def _sensor_adr(model: mujoco.MjModel, name: str) -> int:
    sid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SENSOR, name)
    return int(model.sensor_adr[sid]) if sid >= 0 else -1


def _layout(model: mujoco.MjModel, task: str, params: ArmParams) -> _Layout:
    n = params.n_disks
    adr = np.empty((3, 2, n - 1), dtype=np.int64)
    lim = np.empty((3, 2, n - 1))
    for j in range(3):
        for a, axis in enumerate(("x", "y")):
            for i in range(1, n):
                jid = model.joint(hinge_joint_name(j, axis, i)).id
                adr[j, a, i - 1] = model.jnt_qposadr[jid]
                lim[j, a, i - 1] = model.jnt_range[jid, 1]
    obj_body = {"throw": CUBE_BODY, "hammer": HAMMER_BODY}.get(task)
    return _Layout(
        eef_pos=_sensor_adr(model, EEF_POS_SENSOR),
        eef_linvel=_sensor_adr(model, EEF_LINVEL_SENSOR),
        eef_vel_local=_sensor_adr(model, EEF_VEL_SENSOR),
        cube_origin=_sensor_adr(model, CUBE_ORIGIN_SENSOR),
        pads=tuple(a for a in (_sensor_adr(model, n) for n in PAD_SENSORS) if a >= 0),
        grip_actuator=mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, GRIP_ACTUATOR),
        object_pos=_sensor_adr(model, OBJECT_POS_SENSOR),
        object_linvel=_sensor_adr(model, OBJECT_LINVEL_SENSOR),
        plate=_sensor_adr(model, PLATE_SENSOR),
        weld=mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_EQUALITY, GRIP_WELD),
        hinge_qposadr=adr,
        hinge_limit=lim,
        object_mass_kg=float(model.body(obj_body).mass[0]) if obj_body else 0.0,
    )


def _steps_for(seconds: float, dt: float, what: str) -> int:
    n = round(seconds / dt)
    if n < 1 or abs(n * dt - seconds) > 1e-9 * max(1.0, seconds):
        raise ValueError(f"{what} ({seconds:g} s) is not a whole number of {dt:g} s physics steps")
    return n


def _check_inputs(
    task: str, schedule: Any, release_step: Any, params: ArmParams
) -> tuple[np.ndarray, int | None]:
    check_task(task)
    try:
        sched = check_schedule(schedule, lower_pa=0.0, upper_pa=params.max_pressure_pa)
    except PolicyError as exc:
        raise ValueError(str(exc)) from exc
    try:
        release = check_release_step(
            release_step,
            horizon=sched.shape[0],
            with_release=task in RELEASE_TASKS,
            owner=task,
        )
    except PolicyError as exc:
        raise ValueError(str(exc)) from None
    return sched, release


def _diverged(task: str, preset: str, t: float, why: str) -> SimulationDiverged:
    return SimulationDiverged(
        f"simulation diverged ({task}, preset {preset}) at t = {t:.3f} s: {why}; "
        "the schedule or parameters drive the physics unstable",
        task=task,
        preset=preset,
        time_s=t,
    )


_WARNING_TEXT = {
    mujoco.mjtWarning.mjWARN_BADQACC: "NaN/Inf or huge accelerations",
    mujoco.mjtWarning.mjWARN_BADQPOS: "NaN/Inf or huge positions",
    mujoco.mjtWarning.mjWARN_BADQVEL: "NaN/Inf or huge velocities",
}
_BAD_WARNINGS = tuple(_WARNING_TEXT)


def _check_warnings(warn: Any, task: str, preset: str, t: float) -> None:
    bad = [w for w in _BAD_WARNINGS if warn[w].number]
    if bad:
        what = ", ".join(_WARNING_TEXT[w] for w in bad)
        raise _diverged(task, preset, t, f"MuJoCo found {what} (by this time)")


def check_rollout(
    task: str,
    pressure_schedule_pa: Any,
    *,
    release_step: int | None = None,
    preset: str | Preset = "reference",
    params: ArmParams | None = None,
) -> None:
    """Raise ValueError for what ``rollout`` would refuse (task, schedule, release step, a
    horizon whose control step is not a whole number of physics steps), without simulating."""
    p = get_preset(preset)
    params = effective_params(p, params)
    schedule, _ = _check_inputs(task, pressure_schedule_pa, release_step, params)
    dt = float(compiled_model(task, p, params).opt.timestep)
    horizon = schedule.shape[0]
    try:
        _steps_for(EPISODE_S / horizon, dt, "a control step")
    except ValueError as exc:
        raise ValueError(f"horizon {horizon} cannot be simulated: {exc}") from None


def rollout(
    task: str,
    pressure_schedule_pa: np.ndarray,
    *,
    release_step: int | None = None,
    preset: str | Preset = "reference",
    record_hz: float = 100.0,
    params: ArmParams | None = None,
    record_qpos: bool = False,
    command_hold: str = "zero",
    objective_rule: str = "paper",
) -> RolloutResult:
    """Simulate one 5 s episode of ``task`` under an (H, 12) pressure schedule (Pa).

    Row t of the schedule is commanded during control step t (5 s / H from t·5/H), held or
    ramped as ``command_hold`` says (module docstring); the arm starts at rest, straight, with
    all chamber pressures zero. ``objective_rule`` picks the scoring rule of ``objective``.
    Deterministic: the same inputs give bit-identical results. The trajectory is sampled every
    round(1 / (record_hz · timestep)) physics steps (at least one), t = 0 included; the
    objective does not depend on ``record_hz``.

    Raises:
        ValueError: unknown task/preset/command hold/objective rule, a bad schedule (shape,
            non-finite, outside [0, max pressure], naming step and chamber), or a bad
            release_step/record_hz.
        SimulationDiverged: the physics became unstable (never returns NaN).
    """
    p = get_preset(preset)
    params = effective_params(p, params)
    hold = check_command_hold(command_hold)
    rule = check_objective_rule(objective_rule)
    schedule, release = _check_inputs(task, pressure_schedule_pa, release_step, params)
    if not (isinstance(record_hz, int | float) and math.isfinite(record_hz) and record_hz > 0):
        raise ValueError(f"record_hz must be a positive number, got {record_hz!r}")
    t0 = time.perf_counter()
    ep = Episode(
        task,
        horizon=schedule.shape[0],
        preset=p,
        record_hz=float(record_hz),
        params=params,
        record_qpos=record_qpos,
        command_hold=hold,
        objective_rule=rule,
    )
    for row in schedule:
        ep._advance(row, release is not None and ep.steps_done >= release)
    out = ep.result()
    out.wall_s = time.perf_counter() - t0
    return out


def command_rows(schedule: np.ndarray, release: int | None, grip: bool) -> np.ndarray:
    """The (H, nu) command rows: the schedule, plus the gripper's (1 closed up to t_R, then 0)."""
    if not grip:
        return schedule
    assert release is not None
    closed = (np.arange(schedule.shape[0]) < release).astype(np.float64)
    return np.column_stack([schedule, closed])


def linear_commands(rows: np.ndarray, n_ctrl: int) -> np.ndarray:
    """(H·n_ctrl, nu) per-physics-step commands of the ``"linear"`` hold.

    Within control step c, physics step τ = 0..n_ctrl − 1 applies prev + (row_c − prev)·τ/(n_ctrl
    − 1), prev being row c − 1 (all zeros before row 0).
    """
    horizon, nu = rows.shape
    prev = np.vstack([np.zeros((1, nu)), rows[:-1]])
    tau = np.arange(n_ctrl) / max(n_ctrl - 1, 1) if n_ctrl > 1 else np.ones(1)
    out = prev[:, None, :] + (rows - prev)[:, None, :] * tau[None, :, None]
    return out.reshape(horizon * n_ctrl, nu)


class Episode:
    """One episode, one control step at a time: the loop ``rollout`` itself runs.

        ep = Episode("throw", horizon=10, preset="fast", command_hold="linear")
        for t in range(1, 11):
            ep.step(row_pa, open_gripper=t > t_r)  # row_pa: (12,) Pa, commanded in step t
            ep.reading(EEF_LINVEL_SENSOR)        # a sensor at the end of step t
        res = ep.result()                        # what ``rollout`` gives for the same rows

    ``open_gripper`` (throw only) is the gripper command of this step: once open it stays open,
    and t_R is the number of steps before it opened (never opened: t_R = H); it must stay closed
    in step 1, as t_R ≥ 1. Holds, grasp and scoring are ``rollout``'s
    (module docstring); ``rollout`` is this class driven row by row, so both give bit-identical
    results. The arm starts at rest at construction; sensors then read the state at t = 0.

    Raises (``step``): ValueError for a bad row or a step past the horizon; SimulationDiverged
    as ``rollout`` does.
    """

    def __init__(
        self,
        task: str,
        *,
        horizon: int = 10,
        preset: str | Preset = "reference",
        record_hz: float = 100.0,
        params: ArmParams | None = None,
        record_qpos: bool = False,
        command_hold: str = "zero",
        objective_rule: str = "paper",
    ) -> None:
        check_task(task)
        p = get_preset(preset)
        params = effective_params(p, params)
        self.command_hold = check_command_hold(command_hold)
        self.objective_rule = check_objective_rule(objective_rule)
        if isinstance(horizon, bool) or not isinstance(horizon, int | np.integer) or horizon < 1:
            raise ValueError(
                f"horizon must be a whole number of control steps ≥ 1, got {horizon!r}"
            )
        if not (isinstance(record_hz, int | float) and math.isfinite(record_hz) and record_hz > 0):
            raise ValueError(f"record_hz must be a positive number, got {record_hz!r}")
        self.task, self.preset, self.params = task, p, params
        self.horizon = horizon = int(horizon)
        self.record_qpos = record_qpos
        self.model = model = compiled_model(task, p, params)
        self.dt = dt = float(model.opt.timestep)
        self.n_ctrl = n_ctrl = _steps_for(EPISODE_S / horizon, dt, "a control step")
        self.n_obj = n_obj = _steps_for(1.0 / OBJECTIVE_HZ, dt, "the 100 Hz objective grid")
        self.n_rec = n_rec = max(1, round(1.0 / (float(record_hz) * dt)))
        n_total = n_ctrl * horizon
        self.points = points = sorted(
            set(range(0, n_total + 1, n_rec))
            | set(range(0, n_total + 1, n_obj))
            | set(range(0, n_total + 1, n_ctrl))
        )
        self._gaps = np.diff(points, prepend=0).tolist()
        n_pts = len(points)
        self.layout = lay = _layout(model, task, params)
        self.has_grip = lay.grip_actuator >= 0
        self.nu = N_CHAMBERS + int(self.has_grip)
        self.data = data = mujoco.MjData(model)
        self.qpos = np.empty((n_pts, model.nq))
        self.act = np.empty((n_pts, model.na))
        self.sensors = np.empty((n_pts, model.nsensordata))
        self.steps_done = 0
        self.release: int | None = None  # t_R once the gripper command opened
        self._prev_row = np.zeros(self.nu)  # the "linear" ramp starts from all zeros
        self._tau = np.arange(n_ctrl) / max(n_ctrl - 1, 1) if n_ctrl > 1 else np.ones(1)
        # mj_step1 computes position/velocity quantities and sensors of the current state; the
        # following mj_step2 finishes that physics step. So every sample reads the state
        # exactly at its time at no extra cost (acceleration-stage sensors, the plate's touch
        # reading, come from the last completed step).
        mujoco.mj_step1(model, data)
        self._record(0)
        self._idx = 1

    def _record(self, idx: int) -> None:
        self.qpos[idx] = self.data.qpos
        self.act[idx] = self.data.act
        self.sensors[idx] = self.data.sensordata

    def reading(self, sensor: str) -> np.ndarray:
        """Sensor ``sensor``'s latest reading (a copy): at the end of the last step done."""
        sid = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_SENSOR, sensor)
        if sid < 0:
            raise ValueError(f"no sensor {sensor!r} in the {self.task} model")
        adr, dim = int(self.model.sensor_adr[sid]), int(self.model.sensor_dim[sid])
        return self.sensors[self._idx - 1 if self._idx else 0, adr : adr + dim].copy()

    def step_samples(self) -> np.ndarray:
        """Indices into the recorded arrays (``sensors``, ``qpos``, ``act``) of the last step
        done's samples after its start, its end included."""
        c = self.steps_done
        lo, hi = (c - 1) * self.n_ctrl, c * self.n_ctrl
        pts = np.asarray(self.points[: self._idx])
        return np.flatnonzero((pts > lo) & (pts <= hi))

    def step(self, pressures_pa: np.ndarray, *, open_gripper: bool = False) -> None:
        """Run the next control step with chamber commands ``pressures_pa`` (12,), Pa."""
        if self.steps_done >= self.horizon:
            raise ValueError(f"the episode has {self.horizon} control steps; all are done")
        t = self.steps_done + 1
        try:
            row = check_schedule(
                np.asarray(pressures_pa, dtype=np.float64).reshape(1, -1),
                lower_pa=0.0,
                upper_pa=self.params.max_pressure_pa,
            )[0]
        except PolicyError as exc:
            raise ValueError(f"control step {t}: {exc}") from exc
        if open_gripper and self.task != "throw":
            raise ValueError(f"the gripper only exists in throw, not {self.task}")
        if open_gripper and t == 1:
            raise ValueError("the gripper holds the cube in step 1 (release step t_R ≥ 1)")
        self._advance(row, bool(open_gripper))

    def _advance(self, row: np.ndarray, open_gripper: bool) -> None:
        c = self.steps_done  # 0-based control step
        model, data, lay, n_ctrl = self.model, self.data, self.layout, self.n_ctrl
        first_open = open_gripper and self.release is None
        if first_open:
            self.release = c  # steps 1..c held the cube
        if self.has_grip:
            # the gripper is closed for steps 1..t_R, open after
            row = np.append(row, 1.0 if self.release is None else 0.0)
        # The weld (if any) lets go when the gripper command opens: at the end of step t_R when
        # held; in the last physics step of step t_R + 1 when ramped (never for t_R = H).
        weld_off = first_open and lay.weld >= 0
        step, step1, step2 = mujoco.mj_step, mujoco.mj_step1, mujoco.mj_step2
        ctrl = data.ctrl
        held = self.command_hold == "zero"
        if held:
            ctrl[:] = row
            if weld_off:
                data.eq_active[lay.weld] = 0
                step1(model, data)  # rebuild the constraints without the weld
            per_step = None
        else:
            prev = self._prev_row
            per_step = prev[None, :] + (row - prev)[None, :] * self._tau[:, None]
        start, end = c * n_ctrl, (c + 1) * n_ctrl
        idx = self._idx
        while idx < len(self.points) and self.points[idx] <= end:
            k, gap = self.points[idx], self._gaps[idx]
            if per_step is None:
                step2(model, data)
                if gap > 1:
                    step(model, data, gap - 1)
                step1(model, data)
            else:
                first = k - gap
                for kk in range(first, k):
                    ctrl[:] = per_step[kk - start]
                    if weld_off and kk == end - 1:
                        data.eq_active[lay.weld] = 0
                        if kk == first:
                            step1(model, data)  # rebuild the constraints without the weld
                    if kk == first:
                        step2(model, data)
                    else:
                        step(model, data)
                step1(model, data)
            self._record(idx)
            idx += 1
        self._idx = idx
        self._prev_row = row
        self.steps_done = c + 1
        # MuJoCo counts unstable states (and resets them) rather than stopping: check the
        # counters once per control step, so a blow-up is caught within 5 s / H.
        _check_warnings(data.warning, self.task, self.preset.name, end * self.dt)

    def result(self) -> RolloutResult:
        """The episode's RolloutResult (as ``rollout`` gives); ValueError before the last step."""
        if self.steps_done < self.horizon:
            raise ValueError(
                f"the episode has {self.horizon} control steps; {self.steps_done} are done"
            )
        release = None
        if self.task == "throw":
            release = self.release if self.release is not None else self.horizon
        return _finish(self, release)


def _finish(ep: Episode, release: int | None) -> RolloutResult:
    """The RolloutResult of a finished episode: checks, objectives, trajectory."""
    task, p, params, lay, dt = ep.task, ep.preset, ep.params, ep.layout, ep.dt
    qpos, act, sensors, points = ep.qpos, ep.act, ep.sensors, ep.points
    horizon, n_ctrl, n_obj, n_rec = ep.horizon, ep.n_ctrl, ep.n_obj, ep.n_rec
    hold, rule, record_qpos, name = ep.command_hold, ep.objective_rule, ep.record_qpos, p.name
    n_pts = len(points)
    _check_warnings(ep.data.warning, task, name, points[-1] * dt)

    tip_pos = sensors[:, lay.eef_pos : lay.eef_pos + 3]
    tip_vel = sensors[:, lay.eef_linvel : lay.eef_linvel + 3]
    if lay.object_pos >= 0:
        obj_pos = sensors[:, lay.object_pos : lay.object_pos + 3]
        obj_vel = sensors[:, lay.object_linvel : lay.object_linvel + 3]
    else:
        obj_pos = obj_vel = np.zeros((n_pts, 3))
    plate = sensors[:, lay.plate] if lay.plate >= 0 else np.zeros(n_pts)

    for arr, what in ((qpos, "positions"), (sensors, "sensor readings"), (act, "pressures")):
        bad = ~np.isfinite(arr).all(axis=1)
        if bad.any():
            raise _diverged(task, name, points[int(np.argmax(bad))] * dt, f"non-finite {what}")
    tip_speed = np.linalg.norm(tip_vel, axis=1)
    if tip_speed.max() > MAX_PLAUSIBLE_SPEED_M_S:
        i = int(np.argmax(tip_speed > MAX_PLAUSIBLE_SPEED_M_S))
        raise _diverged(task, name, points[i] * dt, f"tip speed {tip_speed[i]:.3g} m/s")

    pts = np.asarray(points)
    is_rec, is_obj, is_ctrl = pts % n_rec == 0, pts % n_obj == 0, (pts % n_ctrl == 0) & (pts > 0)
    ctrl_idx = np.flatnonzero(is_ctrl)  # ends of steps 1..H
    speed_grid = tip_speed[is_obj]

    lost: bool | None = None
    last_contact: float | None = None
    if task == "tip_speed":
        objective = float(speed_grid.max())
        terms = {"max_tip_speed": objective}
        by_rule = dict.fromkeys(OBJECTIVE_RULES, objective)
    elif task == "throw":
        assert release is not None
        by_rule, terms = _throw_objectives(
            tip_speed[ctrl_idx],
            obj_pos[-1],
            sensors[-1, lay.cube_origin : lay.cube_origin + 3],
            release,
            rule,
        )
        if lay.pads:
            touching = (sensors[:, list(lay.pads)] > 0.0).any(axis=1) & is_obj
            hit = np.flatnonzero(touching)
            last_contact = float(pts[hit[-1]] * dt) if hit.size else None
            release_s = release * n_ctrl * dt
            lost = last_contact is None or last_contact < release_s - 0.5 * dt
        else:
            lost = False
    else:
        g = np.asarray(params.plate.centre_m)
        m = lay.object_mass_kg
        force = plate[ctrl_idx]
        steps = np.arange(1, horizon + 1)
        late = steps >= 0.7 * horizon - 1e-9
        momentum = m * np.abs(obj_vel[ctrl_idx, 2])
        dist = np.where(late, np.linalg.norm(obj_pos[ctrl_idx] - g, axis=1), 0.0)
        paper = (momentum.sum() + force.sum() - dist.sum()) / 1000.0
        # published: the tip velocimeter's own z, the tip site's distance, steps t > 0.7H
        vz_local = sensors[ctrl_idx, lay.eef_vel_local + 2]
        pub_late = steps > 0.7 * horizon + 1e-9
        pub_momentum = m * np.abs(vz_local)
        pub_dist = np.where(pub_late, np.linalg.norm(tip_pos[ctrl_idx] - g, axis=1), 0.0)
        published = (pub_momentum.sum() + force.sum() - pub_dist.sum()) / 1000.0
        by_rule = {"paper": float(paper), "published": float(published)}
        if rule == "paper":
            terms = {
                "momentum_sum": float(momentum.sum()),
                "force_sum_n": float(force.sum()),
                "distance_sum_m": float(dist.sum()),
            }
        else:
            terms = {
                "momentum_sum": float(pub_momentum.sum()),
                "force_sum_n": float(force.sum()),
                "distance_sum_m": float(pub_dist.sum()),
            }
    objective = by_rule[rule]

    bend_q = qpos[:, lay.hinge_qposadr]  # (n_pts, 3, 2, n-1)
    at_limit = np.abs(bend_q) >= BEND_LIMIT_FRACTION * lay.hinge_limit
    hits = [int(j) for j in np.flatnonzero(at_limit.any(axis=(0, 2, 3)))]

    rec = np.flatnonzero(is_rec)
    traj = Trajectory(
        time_s=pts[rec] * dt,
        tip_pos_m=tip_pos[rec],
        tip_vel_m_s=tip_vel[rec],
        tip_speed_m_s=tip_speed[rec],
        object_pos_m=obj_pos[rec],
        plate_force_n=plate[rec],
        pressure_pa=act[rec],
        bend_rad=bend_q[rec].sum(axis=-1),
        qpos=qpos[rec].copy() if record_qpos else None,
    )
    return RolloutResult(
        task=task,
        preset=name,
        objective=objective,
        max_tip_speed=float(speed_grid.max()),
        tip_speed_100hz=speed_grid,
        wall_s=0.0,
        bend_limit_hits=hits,
        release_step=release,
        peak_plate_force_n=float(plate.max()),
        objective_terms=terms,
        trajectory=traj,
        timestep_s=dt,
        n_disks=params.n_disks,
        command_hold=hold,
        objective_rule=rule,
        objective_by_rule=by_rule,
        cube_lost_before_release=lost,
        last_pad_contact_s=last_contact,
    )


def published_throw_steps(release: int, horizon: int) -> np.ndarray:
    """1-based steps whose tip speed the published throw rule counts (module docstring)."""
    steps = [t for t in range(1, horizon) if t < release]
    if 3 <= release <= horizon - 1:
        steps.append(release)
    return np.asarray(steps, dtype=np.int64)


def _throw_objectives(
    speed_at_step_end: np.ndarray,
    cube_centre: np.ndarray,
    cube_origin: np.ndarray,
    release: int,
    rule: str,
) -> tuple[dict[str, float], dict[str, float]]:
    horizon = speed_at_step_end.shape[0]
    paper_sum = float(speed_at_step_end[:release].sum())
    paper_d = float(np.linalg.norm(cube_centre))
    counted = published_throw_steps(release, horizon)
    pub_sum = float(speed_at_step_end[counted - 1].sum()) if counted.size else 0.0
    pub_d = float(np.linalg.norm(cube_origin))
    by_rule = {"paper": paper_sum + paper_d, "published": pub_sum + pub_d}
    if rule == "paper":
        return by_rule, {"tip_speed_sum": paper_sum, "cube_distance_m": paper_d}
    return by_rule, {"tip_speed_sum": pub_sum, "cube_distance_m": pub_d}
