"""`handful sim`: the installed console script in a real subprocess for the main paths, and the
same typer app in-process (CliRunner) for the long list of bad inputs, to keep the suite fast."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import mujoco
import numpy as np
import pytest
from typer.testing import CliRunner

from app.cli import app
from app.sim import Trajectory

HANDFUL = shutil.which("handful") or str(Path(sys.executable).with_name("handful"))


def run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [HANDFUL, "sim", *args], capture_output=True, text=True, timeout=120, check=False
    )


def run_in_process(*args: str) -> tuple[int, str]:
    """(exit code, stderr) of `handful sim ARGS` run by the same typer app, in this process."""
    result = CliRunner().invoke(app, ["sim", *args])
    return result.exit_code, result.stderr


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--task", "juggle", "--random"], "unknown task 'juggle'"),
        (["--task", "hammer", "--theta", ",".join(["0.5"] * 9 + ["1.2"])], "θ[9] = 1.2 is outside"),
    ],
)
def test_console_script_bad_input_exits_with_one_line(args: list[str], message: str) -> None:
    out = run(*args)
    assert out.returncode == 2 and out.stdout == ""
    assert message in out.stderr
    assert out.stderr.count("\n") == 1 and "Traceback" not in out.stderr


def test_console_script_refuses_negative_pressure_file(tmp_path: Path) -> None:
    doc = {"pressures_pa": [[1e5] * 12] * 9 + [[-3.0] + [1e5] * 11]}
    out = run("--task", "hammer", "--schedule", _schedule_file(tmp_path, doc))
    assert out.returncode == 2
    assert out.stderr == (
        "handful sim: error: step 10, chamber j0.x+: -3.0 Pa is outside the allowed "
        "[0.0, 275800.0] Pa\n"
    )


def test_random_hammer_json_shape(tmp_path: Path) -> None:
    traj_path = tmp_path / "t.npz"
    xml_path = tmp_path / "m.xml"
    out = run(
        "--task",
        "hammer",
        "--preset",
        "fast",
        "--random",
        "--seed",
        "3",
        "--json",
        "--save-trajectory",
        str(traj_path),
        "--export-xml",
        str(xml_path),
    )
    assert out.returncode == 0, out.stderr
    summary = json.loads(out.stdout)
    for key in ("objective", "max_tip_speed", "tip_speed_100hz", "wall_s", "task", "preset"):
        assert key in summary
    assert summary["task"] == "hammer" and summary["preset"] == "fast"
    assert len(summary["tip_speed_100hz"]) == 501
    assert summary["max_tip_speed"] == pytest.approx(max(summary["tip_speed_100hz"]), abs=1e-5)
    assert summary["seed"] == 3 and len(summary["theta"]) == 10
    assert np.asarray(summary["pressures_pa"]).shape == (10, 12)
    traj = Trajectory.from_npz(traj_path)
    assert traj.qpos is not None and traj.qpos.shape == (501, 54)
    np.testing.assert_allclose(traj.tip_speed_m_s, summary["tip_speed_100hz"], atol=1e-6)
    assert mujoco.MjModel.from_xml_path(str(xml_path)).nu == 12
    # the same seed gives the same episode
    again = json.loads(
        run("--task", "hammer", "--preset", "fast", "--random", "--seed", "3", "--json").stdout
    )
    assert again["objective"] == summary["objective"]


def test_theta_and_schedule_file_give_the_same_throw(tmp_path: Path) -> None:
    theta = "0.1,0.9,0.3,0.7,0.5,0.2,0.8,0.4,0.6,0.05,0.35"
    by_theta = run(
        "--task", "throw", "--preset", "fast", "--theta", theta, "--levels", "5", "--json"
    )
    assert by_theta.returncode == 0, by_theta.stderr
    summary = json.loads(by_theta.stdout)
    assert summary["release_step"] == 4 and summary["levels"] == 5
    path = tmp_path / "s.json"
    path.write_text(json.dumps({"pressures_pa": summary["pressures_pa"], "release_step": 4}))
    by_file = run("--task", "throw", "--preset", "fast", "--schedule", str(path), "--json")
    assert by_file.returncode == 0, by_file.stderr
    assert json.loads(by_file.stdout)["objective"] == summary["objective"]


def test_hold_and_rule_reach_the_episode_and_its_json() -> None:
    theta = "0.1,0.9,0.3,0.7,0.5,0.2,0.8,0.4,0.6,0.05,0.35"
    base = ["--task", "throw", "--preset", "fast", "--theta", theta, "--json"]
    default = json.loads(run(*base).stdout)
    assert (default["command_hold"], default["objective_rule"]) == ("zero", "paper")
    out = run(*base, "--command-hold", "linear", "--objective", "published")
    assert out.returncode == 0, out.stderr
    ramped = json.loads(out.stdout)
    assert (ramped["command_hold"], ramped["objective_rule"]) == ("linear", "published")
    assert ramped["objective"] == ramped["objective_by_rule"]["published"]
    assert ramped["max_tip_speed"] != default["max_tip_speed"]


def test_plain_output_is_one_line() -> None:
    out = run("--task", "tip_speed", "--preset", "fast", "--random")
    assert out.returncode == 0
    assert out.stdout.count("\n") == 1 and "max_tip_speed=" in out.stdout
    assert "command_hold=zero" in out.stdout and "objective_rule=paper" in out.stdout


def _schedule_file(tmp_path: Path, doc: object) -> str:
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(doc) if not isinstance(doc, str) else doc)
    return str(path)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--task", "juggle", "--random"], "unknown task 'juggle'"),
        (["--random"], "--task is required"),
        (["--task", "hammer", "--preset", "ultra", "--random"], "unknown preset 'ultra'"),
        (["--task", "hammer", "--theta", "0.1,0.2"], "θ must have 10 entries"),
        (["--task", "hammer", "--theta", ",".join(["0.5"] * 9 + ["1.2"])], "θ[9] = 1.2 is outside"),
        (["--task", "hammer", "--theta", "a,b"], "comma-separated numbers"),
        (["--task", "hammer", "--random", "--levels", "1"], "--levels must be in 2..1000"),
        (["--task", "hammer", "--random", "--seed", "x"], "--seed must be an integer"),
        (["--task", "hammer"], "give one of --theta"),
        (["--task", "hammer", "--random", "--theta", "0.5"], "give only one of"),
        (["--task", "hammer", "--schedule", "/nonexistent/s.json"], "cannot read"),
        (
            ["--task", "hammer", "--random", "--command-hold", "cubic"],
            "unknown --command-hold 'cubic'; choose one of zero, linear",
        ),
        (
            ["--task", "hammer", "--random", "--objective", "best"],
            "unknown --objective 'best'; choose one of paper, published",
        ),
    ],
)
def test_bad_arguments_exit_nonzero_with_one_line(args: list[str], message: str) -> None:
    code, stderr = run_in_process(*args)
    assert code == 2
    assert message in stderr
    assert stderr.count("\n") == 1 and "Traceback" not in stderr


@pytest.mark.parametrize(
    ("doc", "message"),
    [
        ({"pressures_pa": [[1e5] * 11] * 10}, "rows of 12 numbers"),
        ({"pressures_pa": [[1e5] * 12] * 9 + [[-3.0] + [1e5] * 11]}, "step 10, chamber j0.x+"),
        ({"pressures_pa": [[1e5] * 12] * 9 + [[1e5] * 11 + [4e5]]}, "400000.0 Pa is outside"),
        ({"pressures_pa": [[1e5] * 12] * 10, "release_step": 3}, "applies to throw only"),
        ({"pressures": []}, "must hold"),
        ("{not json", "not valid JSON"),
    ],
)
def test_bad_schedule_files_exit_nonzero(tmp_path: Path, doc: object, message: str) -> None:
    code, stderr = run_in_process(
        "--task", "hammer", "--preset", "fast", "--schedule", _schedule_file(tmp_path, doc)
    )
    assert code == 2
    assert message in stderr and stderr.count("\n") == 1


def test_throw_schedule_needs_a_valid_release_step(tmp_path: Path) -> None:
    rows = [[1e5] * 12] * 10
    code, stderr = run_in_process(
        "--task", "throw", "--schedule", _schedule_file(tmp_path, {"pressures_pa": rows})
    )
    assert code == 2 and "throw needs release_step" in stderr
    doc = {"pressures_pa": rows, "release_step": 12}
    code, stderr = run_in_process(
        "--task", "throw", "--preset", "fast", "--schedule", _schedule_file(tmp_path, doc)
    )
    assert code == 2 and "release_step must be in 1..10" in stderr
