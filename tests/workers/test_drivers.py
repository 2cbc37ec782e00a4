"""Driver lookup by name, the standin robot (noise, drift, faults) and the recording wrapper."""

from __future__ import annotations

import json
import threading
import time

import numpy as np
import pytest

from app.policy import Policy, PressureLimits
from app.sim import rollout
from app.workers.drivers import DriverCommand, DriverError, available_drivers, load_driver
from app.workers.drivers.recording import read_log
from app.workers.drivers.standin import StandinDriver
from app.workers.objective import tip_speed_from_tracking

LIMITS = PressureLimits()
POLICY = Policy(levels=5, limits=LIMITS)


def command(theta: np.ndarray, trial_id: int = 1) -> DriverCommand:
    """A tip_speed command for θ under the paper's hardware limits."""
    schedule = POLICY.decode(theta).pressure_schedule_pa
    return DriverCommand(
        trial_id, "tip_speed", schedule, None, POLICY.step_s, np.asarray(LIMITS.nominal_pa)
    )


def quiet(tmp_path, **options: str) -> StandinDriver:
    """A standin with faults switched off (noise and drift on)."""
    opts = {
        "preset": "fast",
        "state_file": str(tmp_path / "standin.json"),
        "fault_probability": "0",
        "tracker_loss_probability": "0",
    }
    opts.update(options)
    return StandinDriver(**opts)


def test_builtin_drivers_resolve_by_name_and_import_path():
    assert {"standin", "recording"} <= set(available_drivers())
    by_name = load_driver("standin", state_file="", preset="fast")
    by_path = load_driver("app.workers.drivers.standin:StandinDriver", state_file="")
    assert type(by_name) is type(by_path) is StandinDriver


@pytest.mark.parametrize(
    ("name", "options", "message"),
    [
        ("nosuch", {}, "unknown driver 'nosuch'"),
        ("nosuch.module:Driver", {}, "cannot import driver module"),
        ("app.workers.drivers.standin:Nope", {}, "has no driver factory 'Nope'"),
        ("standin", {"wheels": "4"}, "rejected its options ['wheels']"),
        ("standin", {"dropout": "lots"}, "dropout='lots' is not a number"),
        ("standin", {"realtime": "maybe"}, "expected true/false"),
        ("recording", {"inner": "standin"}, "needs -o log=PATH"),
        ("app.policy:PressureLimits", {}, "lacks the method(s) execute, abort, close"),
    ],
)
def test_bad_driver_names_and_options_say_what_is_wrong(name, options, message):
    with pytest.raises(DriverError) as err:
        load_driver(name, **options)
    assert message in str(err.value)


def test_standin_tracking_is_a_noisy_90hz_view_of_the_simulated_tip(tmp_path):
    theta = np.random.default_rng(3).random(POLICY.dim)
    cmd = command(theta)
    driver = quiet(tmp_path, bias_step_pa="0", stiffness_step="0")
    streamed = []
    ex = driver.execute(cmd, on_sample=streamed.append)
    assert ex.fault is None
    np.testing.assert_array_equal(ex.executed_pressure_schedule_pa, cmd.pressure_schedule_pa)
    n = len(ex.tracking.time_s)
    assert len(streamed) == n and 0.97 * 451 <= n <= 451  # 90 Hz over 5 s, a few dropped
    assert np.all(np.diff(ex.tracking.time_s) > 0)
    true = rollout("tip_speed", cmd.pressure_schedule_pa, preset="fast", record_hz=1000.0)
    traj = true.trajectory
    ref_pos = np.stack(
        [np.interp(ex.tracking.time_s, traj.time_s, traj.tip_pos_m[:, k]) for k in range(3)], 1
    )
    pos_err = ex.tracking.tip_pos_m - ref_pos
    assert 0.5e-3 < pos_err.std() < 2e-3  # millimetre noise, not zero and not centimetres
    # The objective comes from the noisy stream and lands near the simulator's own number.
    measured = tip_speed_from_tracking(ex.tracking)
    assert measured != true.max_tip_speed
    assert abs(measured - true.max_tip_speed) < 0.1 * true.max_tip_speed


def test_standin_drift_continues_across_restarts_and_is_seeded(tmp_path):
    cmd = command(np.full(POLICY.dim, 0.3))
    state = tmp_path / "standin.json"
    first = quiet(tmp_path, seed="7", state_file=str(state))
    a = [first.execute(cmd).info for _ in range(2)]
    saved = json.loads(state.read_text())
    assert saved["n_trials"] == 2 and saved["seed"] == 7
    restarted = quiet(tmp_path, seed="7", state_file=str(state))  # a worker restart
    b = restarted.execute(cmd).info
    assert b["robot_trial"] == 3
    uninterrupted = quiet(tmp_path, seed="7", state_file=str(tmp_path / "other.json"))
    c = [uninterrupted.execute(cmd).info for _ in range(3)]
    assert [i["stiffness_scale"] for i in (*a, b)] == [i["stiffness_scale"] for i in c]
    assert len({i["stiffness_scale"] for i in c}) == 3  # it does drift
    # The same command gives a different measurement as the robot drifts.
    d = quiet(tmp_path, seed="7", state_file="", velocity_noise_m_s="0", position_noise_m="0")
    speeds = {round(tip_speed_from_tracking(d.execute(cmd).tracking), 6) for _ in range(3)}
    assert len(speeds) == 3


def test_standin_faults_at_high_tip_speed_vent_to_nominal(tmp_path):
    cmd = command(np.random.default_rng(3).random(POLICY.dim))
    driver = quiet(tmp_path, fault_speed_m_s="0.2", fault_probability="1")
    ex = driver.execute(cmd)
    assert ex.fault is not None and ex.fault.startswith("I2C fault at t=")
    fault_t = float(ex.fault.split("t=")[1].split(" ")[0])
    assert ex.tracking.time_s.max() <= fault_t + 1e-9
    done = int(np.ceil(fault_t / cmd.step_s - 1e-9))
    assert 1 <= done < cmd.horizon
    np.testing.assert_array_equal(
        ex.executed_pressure_schedule_pa[:done], cmd.pressure_schedule_pa[:done]
    )
    np.testing.assert_array_equal(
        ex.executed_pressure_schedule_pa[done:],
        np.broadcast_to(cmd.nominal_pa, (cmd.horizon - done, 12)),
    )


def test_recording_driver_logs_every_command_before_running_it(tmp_path):
    log = tmp_path / "commands.jsonl"
    driver = load_driver(
        "recording",
        inner="standin",
        log=str(log),
        **{"inner.preset": "fast", "inner.state_file": "", "inner.tracker_loss_probability": "0"},
    )
    assert driver.max_pressure_pa == StandinDriver.max_pressure_pa
    cmds = [command(np.full(POLICY.dim, v), trial_id=i) for i, v in enumerate((0.1, 0.9))]
    for c in cmds:
        driver.execute(c)
    logged = read_log(log)
    assert [e["trial_id"] for e in logged] == [0, 1]
    for entry, c in zip(logged, cmds, strict=True):
        np.testing.assert_array_equal(entry["pressure_schedule_pa"], c.pressure_schedule_pa)


def test_standin_abort_stops_a_realtime_run_and_vents_to_nominal(tmp_path):
    cmd = command(np.full(POLICY.dim, 0.7))
    driver = quiet(tmp_path, realtime="true")
    threading.Timer(1.2, driver.abort).start()
    t0 = time.monotonic()
    ex = driver.execute(cmd)
    assert time.monotonic() - t0 < 4.0  # not the whole 5 s
    assert ex.fault is not None and ex.fault.startswith("aborted by the worker")
    assert 0.5 < ex.tracking.time_s[-1] < 3.0
    done = int(np.ceil(ex.tracking.time_s[-1] / cmd.step_s - 1e-9))
    np.testing.assert_array_equal(
        ex.executed_pressure_schedule_pa[done:],
        np.broadcast_to(cmd.nominal_pa, (cmd.horizon - done, 12)),
    )


def test_standin_runs_the_schedule_with_the_experiments_command_hold(tmp_path):
    theta = np.random.default_rng(5).random(POLICY.dim)
    held = command(theta)
    ramped = DriverCommand(
        1, "tip_speed", held.pressure_schedule_pa, None, POLICY.step_s, held.nominal_pa, "linear"
    )
    driver = quiet(tmp_path, bias_step_pa="0", stiffness_step="0")
    tracking = driver.execute(ramped).tracking
    sched = held.pressure_schedule_pa

    def tip_error_mm(hold: str) -> float:
        traj = rollout("tip_speed", sched, preset="fast", command_hold=hold).trajectory
        ref = np.stack(
            [np.interp(tracking.time_s, traj.time_s, traj.tip_pos_m[:, k]) for k in range(3)], 1
        )
        return float(np.sqrt(((tracking.tip_pos_m - ref) ** 2).sum(axis=1).mean()) * 1e3)

    assert tip_error_mm("linear") < 3.0 < 10 * tip_error_mm("linear") < tip_error_mm("zero")


def test_sim_worker_rolls_out_with_the_experiments_command_hold():
    from app.workers.sim import experiment_command_hold, run_sim_trial

    assert experiment_command_hold({"task": "hammer"}) == "zero"  # older servers: held
    assert experiment_command_hold({"command_hold": "linear"}) == "linear"
    sched = POLICY.decode(np.random.default_rng(2).random(POLICY.dim)).pressure_schedule_pa
    out = run_sim_trial("tip_speed", sched, None, "fast", False, "linear")
    assert out.summary["command_hold"] == "linear"
    want = rollout("tip_speed", sched, preset="fast", command_hold="linear").objective
    assert out.objective == want != rollout("tip_speed", sched, preset="fast").objective
