"""A Gymnasium environment over handful's simulator: one control step (5 s / H) per ``step()``.

    env = HandfulEnv("throw", joint_states=True)     # the paper-matching simulator settings
    obs, info = env.reset(seed=0)
    for _ in range(10):
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
    info["objective"]                                 # the simulator's objective of the episode

**Action**: the 12 chamber pressure commands as fractions of the maximum, in [0, 1]; for
``throw`` a 13th entry, the gripper command as a fraction of full scale, as in the published
environment: below ``GRIP_CLOSED_FROM`` (about 0.001) it is open, else closed. Once open it
stays open; step 1 always holds the cube (the policy's release step t_R ≥ 1), so t_R is the
number of steps before the first open command (never opened: t_R = H). Commands are held or
ramped over each step as ``command_hold`` says (``app.sim.rollout``).

**Observation** (float32): the end effector's linear velocity (world frame, m/s), then the task
object's position (cube or hammer-ball centre, world frame, m; none for ``tip_speed``; the
plate's position is a constant and left out); with ``joint_states=True`` also each continuum
joint's (u, v) bend (rad) and their rates (rad/s): u0, v0, u1, v1, u2, v2, then their rates.

**Reward**: per step, so that an episode's return is the task objective under the chosen scoring
rule (``objective_rule``; equal up to float rounding, the test checks it):

* throw, ``paper``: ‖tip velocity‖ at the step's end while the gripper command is closed
  (t ≤ t_R); plus, at the last step, the cube centre's distance from the world origin.
* throw, ``published``: step t's tip speed when t < t_R, or t = t_R with 3 ≤ t_R ≤ H − 1, never
  step H's; it is paid at step t + 1, when the gripper command shows whether t was t_R; plus,
  at the last step, the cube body origin's distance from the origin.
* hammer: each step's term of the rule's sum (m·|ż| + F − [late]·d) / 1000.
* tip_speed: the growth of the largest tip speed on the 100 Hz grid so far.

``info["objective"]`` at the episode's end is the simulator's own objective (the exact
``rollout`` value for the same commands); ``info["schedule_pa"]`` and ``info["release_step"]``
give the commands as ``rollout`` takes them. An episode whose physics diverges ends there
(terminated, reward 0, ``info["diverged"]``, objective NaN).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from app.policy import (
    HORIZON,
    N_CHAMBERS,
    PAPER_COMMAND_HOLD,
    PAPER_OBJECTIVE_RULE,
    PAPER_PRESET,
)
from app.sim import Episode, SimulationDiverged
from app.sim.model import GRIP_CLOSED_FROM, check_task

_BEND_SENSORS = ("u0", "v0", "u1", "v1", "u2", "v2")
_RATE_SENSORS = ("ud0", "vd0", "ud1", "vd1", "ud2", "vd2")


class HandfulEnv(gym.Env[np.ndarray, np.ndarray]):
    """One simulated episode of ``task``, a control step per ``step()`` (module docstring)."""

    metadata: dict[str, Any] = {"render_modes": []}  # noqa: RUF012 (gymnasium's convention)

    def __init__(
        self,
        task: str = "hammer",
        *,
        joint_states: bool = False,
        preset: str = PAPER_PRESET,
        command_hold: str = PAPER_COMMAND_HOLD,
        objective_rule: str = PAPER_OBJECTIVE_RULE,
        horizon: int = HORIZON,
    ) -> None:
        check_task(task)
        self.task = task
        self.joint_states = bool(joint_states)
        self.horizon = horizon
        self._episode_kwargs = {
            "horizon": horizon,
            "preset": preset,
            "command_hold": command_hold,
            "objective_rule": objective_rule,
            "record_hz": 2.0,  # the control steps' ends are sampled anyway; record little else
        }
        self._ep = Episode(task, **self._episode_kwargs)  # checks the settings now
        self.objective_rule = self._ep.objective_rule
        self.max_pressure_pa = float(self._ep.params.max_pressure_pa)
        n_act = N_CHAMBERS + int(task == "throw")
        self.action_space = gym.spaces.Box(0.0, 1.0, (n_act,), dtype=np.float32)
        n_obs = 3 + (3 if task != "tip_speed" else 0) + (12 if self.joint_states else 0)
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (n_obs,), dtype=np.float32)
        lay = self._ep.layout
        self._plate_centre = np.asarray(self._ep.params.plate.centre_m, dtype=np.float64)
        self._mass = lay.object_mass_kg
        adr = {n: self._sensor_adr(n) for n in (*_BEND_SENSORS, *_RATE_SENSORS)}
        self._joint_adr = np.array([adr[n] for n in (*_BEND_SENSORS, *_RATE_SENSORS)])
        self._t = 0
        self._done = True
        self._rows: list[np.ndarray] = []
        self._best_speed = self._prev_speed = 0.0
        self._obs = np.zeros(n_obs, dtype=np.float32)

    def _sensor_adr(self, name: str) -> int:
        model = self._ep.model
        import mujoco

        sid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SENSOR, name)
        return int(model.sensor_adr[sid])

    def _observe(self, s: np.ndarray) -> np.ndarray:
        lay = self._ep.layout
        parts = [s[lay.eef_linvel : lay.eef_linvel + 3]]
        if self.task != "tip_speed":
            parts.append(s[lay.object_pos : lay.object_pos + 3])
        if self.joint_states:
            parts.append(s[self._joint_adr])
        return np.concatenate(parts).astype(np.float32)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Start a new episode: the arm at rest, straight, all pressures zero (deterministic)."""
        super().reset(seed=seed)
        self._ep = Episode(self.task, **self._episode_kwargs)
        self._t = 0
        self._done = False
        self._rows = []
        self._best_speed = self._prev_speed = 0.0
        self._obs = self._observe(self._ep.sensors[0])
        return self._obs.copy(), {}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        """One control step of the commands ``action`` (module docstring)."""
        if self._done:
            raise RuntimeError("the episode is over: call reset() first")
        a = np.clip(np.asarray(action, dtype=np.float64).reshape(-1), 0.0, 1.0)
        if a.shape != self.action_space.shape:
            raise ValueError(f"action must have shape {self.action_space.shape}, got {a.shape}")
        ep = self._ep
        row = a[:N_CHAMBERS] * self.max_pressure_pa
        self._t += 1
        t = self._t
        released_before = ep.release is not None
        open_cmd = self.task == "throw" and t >= 2 and a[-1] < GRIP_CLOSED_FROM
        opens = released_before or open_cmd
        info: dict[str, Any] = {"step": t}
        try:
            ep.step(row, open_gripper=opens)
            s = ep.sensors[ep._idx - 1]
            if not np.isfinite(s).all():
                raise SimulationDiverged(
                    f"simulation diverged ({self.task}) in control step {t}: non-finite readings",
                    task=self.task,
                    preset=ep.preset.name,
                    time_s=t * ep.n_ctrl * ep.dt,
                )
        except SimulationDiverged as exc:
            self._done = True
            info.update(diverged=True, error=str(exc), objective=float("nan"))
            return self._obs.copy(), 0.0, True, False, info
        self._rows.append(row)
        reward = self._reward(s, t, released_before, opens)
        self._obs = self._observe(s)
        terminated = t >= self.horizon
        if terminated:
            self._done = True
            res = ep.result()
            info.update(
                objective=float(res.objective),
                objective_by_rule=dict(res.objective_by_rule),
                schedule_pa=np.array(self._rows),
                release_step=res.release_step,
                diverged=False,
            )
        return self._obs.copy(), float(reward), terminated, False, info

    def _reward(self, s: np.ndarray, t: int, released_before: bool, opens: bool) -> float:
        ep, lay, horizon, rule = self._ep, self._ep.layout, self.horizon, self.objective_rule
        last = t == horizon
        if self.task == "throw":
            speed = float(np.linalg.norm(s[lay.eef_linvel : lay.eef_linvel + 3]))
            if rule == "paper":
                r = 0.0 if opens else speed  # row t closed ⇔ t ≤ t_R
                if last:
                    r += float(np.linalg.norm(s[lay.object_pos : lay.object_pos + 3]))
                return r
            # published: step t − 1's speed, now that row t tells whether t − 1 was t_R
            prev, self._prev_speed = self._prev_speed, speed
            r = 0.0
            if t >= 2 and not released_before:
                counted = 3 <= t - 1 <= horizon - 1 if opens else True  # t − 1 = t_R, or < t_R
                r = prev if counted else 0.0
            if last:
                r += float(np.linalg.norm(s[lay.cube_origin : lay.cube_origin + 3]))
            return r
        if self.task == "hammer":
            force = float(s[lay.plate])
            g = self._plate_centre
            if rule == "paper":
                vz = float(s[lay.object_linvel + 2])
                late = t >= 0.7 * horizon - 1e-9
                d = float(np.linalg.norm(s[lay.object_pos : lay.object_pos + 3] - g)) if late else 0
            else:
                vz = float(s[lay.eef_vel_local + 2])
                late = t > 0.7 * horizon + 1e-9
                d = float(np.linalg.norm(s[lay.eef_pos : lay.eef_pos + 3] - g)) if late else 0
            return (self._mass * abs(vz) + force - d) / 1000.0
        # tip_speed: the growth of the running maximum on the 100 Hz grid
        idx = ep.step_samples()
        pts = np.asarray(ep.points)[idx]
        on_grid = idx[pts % ep.n_obj == 0]
        if t == 1:
            on_grid = np.concatenate([[0], on_grid])
        vel = ep.sensors[on_grid][:, lay.eef_linvel : lay.eef_linvel + 3]
        best = max(self._best_speed, float(np.linalg.norm(vel, axis=1).max()))
        r, self._best_speed = best - self._best_speed, best
        return r
