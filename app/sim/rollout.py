"""One episode: a pressure schedule in, a trajectory record and the task objective out.

Stepping happens in C: ``mujoco.mj_step(model, data, nstep=k)`` runs between sampling points
(the recording grid, the fixed 100 Hz objective grid and the control-step ends), split as
``mj_step2`` / ``mj_step`` / ``mj_step1`` so that the sensors (world-frame tip and object
position and velocity) describe the state exactly at each point; Python only copies arrays
there. The dynamics are the same whatever ``record_hz`` is.

Objectives (ROBOT.md), with H control steps of 5 s / H each:

* ``throw``: Σ_{t=1}^{t_R} ‖tip velocity at the end of step t‖ + ‖cube centre‖ at 5 s (the
  cube's distance from the robot base's footprint centre, the world origin). The weld holding
  the cube is switched off at the end of step ``release_step`` (1-based).
* ``hammer``: (Σ_{t=1}^{H} m·|ż_t| + F_t − 1[t ≥ 0.7H]·‖x_t − g‖) / 1000, with ż_t and x_t the
  ball centre's vertical velocity and position at the end of step t, m the ball mass, g the
  plate centre, and F_t the plate's touch reading **at the end of step t** (the normal contact
  force inside the plate's sensor volume during the last physics step of control step t), as
  in the published code. Impacts between step ends do not count; pressing at a step's end does.
* ``tip_speed``: the largest tip speed on the 100 Hz grid (every 10 ms) over the 5 s.
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

from app.policy import EPISODE_S, PolicyError, check_schedule
from app.sim.model import (
    CUBE_BODY,
    EEF_LINVEL_SENSOR,
    EEF_POS_SENSOR,
    GRIP_WELD,
    HAMMER_BODY,
    OBJECT_LINVEL_SENSOR,
    OBJECT_POS_SENSOR,
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
    extra: dict[str, Any] = field(default_factory=dict)

    def to_summary(self) -> dict[str, Any]:
        """JSON-able summary (no trajectory arrays except the 100 Hz tip speed)."""
        final_obj = self.trajectory.object_pos_m[-1]
        return {
            "task": self.task,
            "preset": self.preset,
            "objective": float(self.objective),
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
        object_pos=_sensor_adr(model, OBJECT_POS_SENSOR),
        object_linvel=_sensor_adr(model, OBJECT_LINVEL_SENSOR),
        plate=_sensor_adr(model, PLATE_SENSOR),
        weld=model.equality(GRIP_WELD).id if task == "throw" else -1,
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
    horizon = sched.shape[0]
    if task == "throw":
        if release_step is None:
            raise ValueError(f"throw needs release_step in 1..{horizon}")
        if isinstance(release_step, bool) or not isinstance(release_step, int | np.integer):
            raise ValueError(
                f"release_step must be an integer in 1..{horizon}, got {release_step!r}"
            )
        if not 1 <= int(release_step) <= horizon:
            raise ValueError(f"release_step must be in 1..{horizon}, got {release_step}")
        return sched, int(release_step)
    if release_step is not None:
        raise ValueError(f"release_step only applies to throw, not {task}")
    return sched, None


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
) -> RolloutResult:
    """Simulate one 5 s episode of ``task`` under an (H, 12) pressure schedule (Pa).

    Row t of the schedule is commanded for 5 s / H from t·5/H; the arm starts at rest, straight,
    with all chamber pressures zero. Deterministic: the same inputs give bit-identical results.
    The trajectory is sampled every round(1 / (record_hz · timestep)) physics steps (at least
    one), t = 0 included; the objective does not depend on ``record_hz``.

    Raises:
        ValueError: unknown task/preset, a bad schedule (shape, non-finite, outside
            [0, max pressure], naming step and chamber), or a bad release_step/record_hz.
        SimulationDiverged: the physics became unstable (never returns NaN).
    """
    p = get_preset(preset)
    params = effective_params(p, params)
    schedule, release = _check_inputs(task, pressure_schedule_pa, release_step, params)
    if not (isinstance(record_hz, int | float) and math.isfinite(record_hz) and record_hz > 0):
        raise ValueError(f"record_hz must be a positive number, got {record_hz!r}")
    model = compiled_model(task, p, params)
    t0 = time.perf_counter()
    out = _simulate(model, task, p, params, schedule, release, float(record_hz), record_qpos)
    out.wall_s = time.perf_counter() - t0
    return out


def _simulate(
    model: mujoco.MjModel,
    task: str,
    p: Preset,
    params: ArmParams,
    schedule: np.ndarray,
    release: int | None,
    record_hz: float,
    record_qpos: bool,
) -> RolloutResult:
    dt = float(model.opt.timestep)
    horizon = schedule.shape[0]
    n_ctrl = _steps_for(EPISODE_S / horizon, dt, "a control step")
    n_obj = _steps_for(1.0 / OBJECTIVE_HZ, dt, "the 100 Hz objective grid")
    n_rec = max(1, round(1.0 / (record_hz * dt)))
    n_total = n_ctrl * horizon
    points = sorted(
        set(range(0, n_total + 1, n_rec))
        | set(range(0, n_total + 1, n_obj))
        | set(range(0, n_total + 1, n_ctrl))
    )
    n_pts = len(points)
    lay = _layout(model, task, params)

    data = mujoco.MjData(model)
    qpos = np.empty((n_pts, model.nq))
    act = np.empty((n_pts, model.na))
    sensors = np.empty((n_pts, model.nsensordata))
    step, step1, step2 = mujoco.mj_step, mujoco.mj_step1, mujoco.mj_step2
    warn = data.warning
    name = p.name

    # mj_step1 computes position/velocity quantities and sensors of the current state; the
    # following mj_step2 finishes that physics step. So every sample reads the state exactly
    # at its time at no extra cost (acceleration-stage sensors, the plate's touch reading,
    # come from the last completed step).
    ctrl_points = {c * n_ctrl: c for c in range(horizon)}  # step k → control steps done
    gaps = np.diff(points, prepend=0).tolist()
    data.ctrl[:] = schedule[0]
    step1(model, data)
    for idx, (k, gap) in enumerate(zip(points, gaps, strict=True)):
        if gap:
            step2(model, data)
            if gap > 1:
                step(model, data, gap - 1)
            step1(model, data)
        qpos[idx] = data.qpos
        act[idx] = data.act
        sensors[idx] = data.sensordata
        done = ctrl_points.get(k)
        if done is not None:
            # MuJoCo counts unstable states (and resets them) rather than stopping: check
            # the counters once per control step, so a blow-up is caught within 5 s / H.
            _check_warnings(warn, task, name, k * dt)
            data.ctrl[:] = schedule[done]
            if release is not None and done == release:
                data.eq_active[lay.weld] = 0
                step1(model, data)  # rebuild the constraints without the weld
    _check_warnings(warn, task, name, n_total * dt)

    tip_pos = sensors[:, lay.eef_pos : lay.eef_pos + 3]
    tip_vel = sensors[:, lay.eef_linvel : lay.eef_linvel + 3]
    if lay.object_pos >= 0:
        obj_pos = sensors[:, lay.object_pos : lay.object_pos + 3]
        obj_vel = sensors[:, lay.object_linvel : lay.object_linvel + 3]
    else:
        obj_pos = obj_vel = np.zeros((n_pts, 3))
    plate = sensors[:, lay.plate] if lay.plate >= 0 else np.zeros(n_pts)

    # (A release at the end of the last step would change nothing within the episode.)
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

    if task == "tip_speed":
        objective = float(speed_grid.max())
        terms = {"max_tip_speed": objective}
    elif task == "throw":
        assert release is not None
        speed_sum = float(tip_speed[ctrl_idx[:release]].sum())
        distance = float(np.linalg.norm(obj_pos[-1]))
        objective = speed_sum + distance
        terms = {"tip_speed_sum": speed_sum, "cube_distance_m": distance}
    else:
        g = np.asarray(params.plate.centre_m)
        momentum = lay.object_mass_kg * np.abs(obj_vel[ctrl_idx, 2])
        force = plate[ctrl_idx]
        steps = np.arange(1, horizon + 1)
        late = steps >= 0.7 * horizon - 1e-9
        dist = np.where(late, np.linalg.norm(obj_pos[ctrl_idx] - g, axis=1), 0.0)
        objective = float((momentum.sum() + force.sum() - dist.sum()) / 1000.0)
        terms = {
            "momentum_sum": float(momentum.sum()),
            "force_sum_n": float(force.sum()),
            "distance_sum_m": float(dist.sum()),
        }

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
    )
